"""``sensaov view``: inspect a stored buffer from any viewpoint, live, in a browser."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from sensaov_cli.cli import options


@options.command
@options.job_argument
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=8765,
    show_default=True,
    help="TCP port to listen on (0: any free port; the URL is printed).",
)
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to listen on. Keep the loopback address unless others must reach the page: "
    "the page shows the scene's names and saves cameras into the output folder.",
)
@click.option("--open", "open_browser", is_flag=True, help="Open the page in the default browser.")
@options.buffer_option(help="Buffer to inspect (default: <output>/buffer.npz of the job).")
@options.force_option(
    help="Inspect even if the scene or the job changed since the buffer was made."
)
@click.option("--log", "log_requests", is_flag=True, help="Print every request on stderr.")
@options.quiet_option
def view(
    job: Path,
    port: int,
    host: str,
    open_browser: bool,
    buffer_path: Path | None,
    force: bool,
    log_requests: bool,
    quiet: bool,
) -> None:
    """Inspect a stored buffer from any viewpoint, live, in a browser.

    Loads the buffer and the scene once, then serves a self-contained page on
    the loopback address: orbit (drag), pan (right-drag), zoom (wheel) from
    the objective camera; the channel is painted through primary visibility
    after every move (1 spp while dragging, 16 at rest; never a gradient).
    Pick the objective, channel and encoding; click an object for its ranked
    parameters; save the viewpoint as a camera entry for 'sensaov project'
    (YAML, or appended to <output>/<job>_view.yaml, the only file it writes).
    The HTTP interface is in docs/view.md. Ctrl-C (or SIGTERM) stops it.

    \b
    Example:
      sensaov run configs/cbox.yaml            # the buffer, once
      sensaov view configs/cbox.yaml --open    # http://127.0.0.1:8765/
      curl -o v.png 'http://127.0.0.1:8765/api/view?channel=objects&origin=2,1,3'
    """
    from sensaov_cli.job.load import load_job
    from sensaov_cli.live.server import listen, serve
    from sensaov_cli.live.session import open_session
    from sensaov_cli.progress import Progress

    def printed(text: str) -> None:  # a saved camera's YAML, on stdout as it is saved
        click.echo(text, nl=False)
        sys.stdout.flush()

    def log(line: str) -> None:
        click.echo(f"sensaov view: {line}", err=True)

    spec = load_job(job)
    progress = Progress(quiet=quiet)
    server = listen(host, port, on_save=printed, log=log if log_requests else None)
    session = open_session(
        spec, buffer_path=buffer_path or spec.output / "buffer.npz", force=force, progress=progress
    )

    def ready(url: str) -> None:
        click.echo(url)  # stdout: the one thing a script needs
        sys.stdout.flush()
        progress.note(f"serving {url} (Ctrl-C stops)")

    def open_page(url: str) -> None:  # called once the server answers (a browser fetches at once)
        import webbrowser

        try:
            opened = webbrowser.open(url)
        except Exception as error:  # noqa: BLE001 - a browser that fails leaves the server up
            opened, why = False, f": {error}"
        else:
            why = ""
        if not opened:
            click.echo(f"sensaov view: could not open a browser{why}; open {url}", err=True)

    serve(server, session, ready=ready, open_page=open_page if open_browser else None)
