"""The render stage, the only package that imports Mitsuba and Dr.Jit; what leaves it is plain
data (ParamRecords, numpy arrays, VisibilityPass)."""
