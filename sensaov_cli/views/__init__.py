"""Views of a buffer (numpy only): coverage, channels, encoding and the ranked summary.

Everything painted or ranked from a stored buffer without differentiating again; new views
(texel, forward, transport, hierarchy) belong here. See docs/architecture.md.
"""
