"""The job format: a YAML job file, validated into frozen dataclasses (pydantic, PyYAML).

``spec`` holds the dataclasses every stage shares, each field defined once, and imports
neither pydantic nor PyYAML (``markers`` says how a job file writes them and words its
mistakes); ``load`` reads a job file into them, gives the JSON Schema, and writes a copy of
the job with cameras saved from ``sensaov view``. See docs/job-spec.md.
"""
