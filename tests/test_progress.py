import io

from i2pbench.cli import build_parser
from i2pbench.execution.progress import ENV_VAR, bar, quiet


def test_quiet_environment_silences_library_progress_bars(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "1")
    assert quiet() and bar(10, "x").disable
    monkeypatch.setenv(ENV_VAR, "0")
    assert not quiet() and not bar(10, "x").disable


def test_every_long_command_accepts_quiet():
    parser = build_parser()
    for argv in (["run"], ["train", "--out", "x.pt"], ["data", "synth"], ["report", "runs/x"]):
        assert parser.parse_args([*argv, "--quiet"]).quiet is True


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_written_to_a_log_is_plain_lines_a_start_and_an_end_not_a_redraw_per_frame(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    log = io.StringIO()
    with bar(400, "2 combination(s) x 200 frames", stream=log) as progress:
        for _ in range(400):
            progress.update(1)  # 400 updates well inside LOG_INTERVAL: no line between the first and the last
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    assert len(lines) == 2 and lines[0].startswith("2 combination(s) x 200 frames:   0%")
    assert "100%" in lines[1] and "400/400" in lines[1]


def test_a_bar_on_a_terminal_redraws_in_place_and_quiet_writes_nothing(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    screen = Terminal()
    with bar(3, "x", stream=screen) as progress:
        progress.update(3)
    assert screen.getvalue().startswith("\rx:   0%") and "3/3" in screen.getvalue()
    monkeypatch.setenv(ENV_VAR, "1")
    silent = io.StringIO()
    with bar(3, "x", stream=silent) as progress:
        progress.update(3)
    assert silent.getvalue() == ""
