"""``python -m sensaov_cli`` runs the command line"""

from sensaov_cli import interrupts

# First, before click and the commands are imported: a signal during the imports is recorded
# and acted on by the command (exit 130/143, one line), never a traceback from inside an import.
interrupts.install(raising=False)

from sensaov_cli.cli import console  # noqa: E402 - after the signal handlers, on purpose

console()
