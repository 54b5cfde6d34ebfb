"""The wiring of each command: call the stages in order, one module per command.

``pipeline/run.py`` wires ``sensaov run`` (spec -> prepared scene -> loaded scene -> adjoint
-> buffer -> files), ``pipeline/project.py`` ``sensaov project``, and so on; a command's face
(options, ``--help``, printing) is ``cli/<verb>.py``. Each command prepares its scene once
(:func:`sensaov_cli.scene.prepare_scene`) and passes the prepared value down. Nothing
here touches a Mitsuba or Dr.Jit type: the stages hand over plain data.
"""
