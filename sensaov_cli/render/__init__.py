"""The render stage, the only package that imports Mitsuba and Dr.Jit.

Runtime set-up, scene XML preparation and loading, parameter selection, objectives, the
primal/backward passes, primary visibility, the beauty pass and the finite-difference check.
What leaves it is plain data (ParamRecords, numpy arrays, VisibilityPass); docs/architecture.md.
"""
