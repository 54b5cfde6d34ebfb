"""Verification of the gradients the render stage computes: how far each kind can be trusted,
checks against finite differences and forward mode, and repairs where Mitsuba is known wrong."""
