"""The job format: a YAML job file, validated into frozen dataclasses (pydantic, PyYAML).

``spec`` holds the dataclasses, importable without pydantic or PyYAML; ``markers`` says how a
job file writes their fields; ``load`` reads a job file, gives its JSON Schema, writes copies.
"""
