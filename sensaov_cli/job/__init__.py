"""The job format: a YAML job file, validated into frozen dataclasses (pydantic, PyYAML).

``spec`` holds the dataclasses every stage shares, each field defined once, and imports
neither pydantic nor PyYAML; ``load`` reads a job file into them and prints the JSON Schema.
See docs/architecture.md and docs/job-spec.md.
"""
