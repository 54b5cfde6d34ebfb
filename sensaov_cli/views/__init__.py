"""Views of a buffer (numpy only): everything painted or ranked from it without differentiating.

Coverage, channels with their encoding and display scales, texels, forward and transport views,
the hierarchy's rankings and the sunburst's geometry. See docs/architecture.md.
"""
