"""Shared check that a typer command refused its input cleanly (design §15): exit code 2 and an
``error:`` message naming what was wrong, never a traceback."""


def assert_refused(res, *needles):
    """``res`` (a CliRunner result) is a clean refusal whose output names every one of ``needles``."""
    assert res.exit_code == 2, res.output
    assert isinstance(res.exception, SystemExit), res.exception  # a message, not a crash
    out = res.output.replace("\n", "")
    assert "error:" in out and "Traceback" not in out
    for n in needles:
        assert str(n) in out, (n, out)
