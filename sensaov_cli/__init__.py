"""sensaov: sensitivity AOVs for Mitsuba 3 scenes.

Importing this package is cheap: Mitsuba and Dr.Jit are imported only by the stages that
render (scene, adjoint), never by the buffer, queries or the CLI's help.
"""

__version__ = "0.1.0"
