"""Files and text a person or a tool reads (numpy, OpenEXR, OpenImageIO).

Atomic writes, EXR and the layered EXR with Cryptomatte, PNG previews, provenance and the text
tables. Nothing here renders or validates; see docs/architecture.md.
"""
