import io

from rich.console import Console

from seal.progress import MofNCompleteColumn, Progress, TextColumn


def _run(console, log_every):
    with Progress(TextColumn("{task.description}"), MofNCompleteColumn(), console=console, log_every=log_every) as bar:
        job = bar.add_task("recording", total=4, info="")
        for i in range(4):
            bar.update(job, advance=1, info=f"{i} failed")


def test_a_log_file_gets_plain_progress_lines():
    out = io.StringIO()
    _run(Console(file=out, force_terminal=False), log_every=0.0)
    lines = [ln for ln in out.getvalue().splitlines() if ln.startswith("[progress ")]
    assert len(lines) == 4
    assert lines[0].endswith("recording: 1/4 (25%) 0 failed") and lines[-1].endswith("recording: 4/4 (100%) 3 failed")


def test_lines_are_spaced_by_the_interval():
    out = io.StringIO()
    _run(Console(file=out, force_terminal=False), log_every=3600.0)
    assert "[progress " not in out.getvalue()  # an hour has not passed: only rich's own final render


def test_a_terminal_gets_the_bar_not_the_lines():
    out = io.StringIO()
    _run(Console(file=out, force_terminal=True), log_every=0.0)
    assert "[progress " not in out.getvalue()
