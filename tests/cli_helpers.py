"""Running the command line in process for the bad-input tests (test_reliability_inputs,
test_scene_bad_input, test_delivery_bad_input)."""

from __future__ import annotations

from l3gs_opt.cli.main import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of ``l3gs-opt ARGV`` (arguments made text)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(capsys, *argv) -> str:
    """Run the CLI on bad input: exit 2 and stderr exactly one ``error:`` line (blank lines aside),
    which is returned."""
    code, _, err = run_cli(capsys, *argv)
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, err)
    return lines[0]
