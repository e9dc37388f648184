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
