"""Files and text a person or a tool reads (numpy, OpenEXR, OpenImageIO, matplotlib).

Atomic writes, EXR and the layered EXR with Cryptomatte, PNG previews, provenance and the text
tables, the rankings and the sunburst. Nothing here renders or validates; see docs/architecture.md.
"""
