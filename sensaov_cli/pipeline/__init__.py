"""The wiring of each command: call the stages in order, one module per command.

A command's face (options, ``--help``, printing) is ``cli/<verb>.py``. Each command prepares its
scene once (:func:`sensaov_cli.scene.prepare_scene`) and passes the prepared value down.
"""
