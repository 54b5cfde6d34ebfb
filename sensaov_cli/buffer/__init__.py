"""The sensitivity buffer stage (numpy only): the model, its ``.npz`` format and its queries.

Loading and querying a buffer never needs Mitsuba, pydantic or click; see docs/architecture.md.
"""
