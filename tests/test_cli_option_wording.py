"""A bad option value is reported by the option's name, as the user typed it (``--slot-s``), not by
the library field it feeds (``slot_s``); and options that a run would not read are still checked
or refused (twentieth session's sweep of every numeric option with -7 and nan)."""

from __future__ import annotations

import pytest

from cli_helpers import one_error_line, run_cli, tiny_sort_bundle
from l3gs_opt.cli.main import FIELD_OPTIONS, build_parser, option_wording

OPTIONS = {"slot_s": "--slot-s", "fov": "--fov", "jobs": "--jobs", "check_time": "--check-time"}


@pytest.mark.parametrize("text, want", [
    ("slot_s: -7.0: must be a positive number", "--slot-s: -7.0: must be a positive number"),
    ("jobs = -7: must be an integer >= 0", "--jobs = -7: must be an integer >= 0"),
    ("fov_deg[2]: nan", "--fov[2]: nan"),                      # a library alias, an index
    ("ceiling_check_s: inf: must be finite", "--check-time: inf: must be finite"),
    ("slot_s", "--slot-s"),
    # not one of the command's options, or not a leading field: left as it is
    ("bundle: no index.json", "bundle: no index.json"),
    ("slot_seconds: 3", "slot_seconds: 3"),
    ("lumos-1: window start=-7 does not fit", "lumos-1: window start=-7 does not fit"),
    ("the jobs = 3", "the jobs = 3"),
    ("", ""),
])
def test_option_wording(text, want):
    assert option_wording(text, OPTIONS) == want


def test_every_alias_names_an_option_of_some_command():
    parser = build_parser()
    dests = set()
    for action in parser._subparsers._group_actions:
        stack = list(action.choices.values())
        while stack:
            p = stack.pop()
            dests |= set(p.get_default("cli_options") or {})
            for a in p._actions:
                if hasattr(a, "choices") and isinstance(a.choices, dict):
                    stack.extend(a.choices.values())
    assert set(FIELD_OPTIONS.values()) <= dests, set(FIELD_OPTIONS.values()) - dests


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    return tiny_sort_bundle(tmp_path_factory.mktemp("wording"))


def test_simulate_fetch_and_tables_name_the_option(capsys, world, tmp_path):
    sim = ("simulate", world["bundle"], "--trace", "lumos-throughput-mid-11", "--path", world["log"],
           "--method", "sort", "--slots", "2")
    for extra, want in [(("--slot-s", "-7"), "error: --slot-s: -7.0: "),
                        (("--fov", "nan"), "error: --fov: nan: "),
                        (("--bandwidth-bias", "-7"), "error: --bandwidth-bias: -7.0: "),
                        (("--time-limit", "-7"), "error: --time-limit: -7.0: "),
                        (("--mbps", "-7"), "error: --mbps = -7.0 (the target mean, Mbit/s): "),
                        (("--mbps", "1e-320"), "error: --mbps = 1e-320 (the target mean, Mbit/s): ")]:
        assert one_error_line(capsys, *sim, *extra).startswith(want)
    fetch = ("fetch", "http://127.0.0.1:9/", "--trace", "lumos-throughput-mid-11", "--path", world["log"],
             "--method", "sort", "--out", tmp_path / "f")
    assert one_error_line(capsys, *fetch, "--retry-s", "-7").startswith("error: --retry-s: -7.0: ")
    assert one_error_line(capsys, *fetch, "--width", "-7").startswith("error: --width: -7: ")
    assert one_error_line(capsys, *fetch, "--catalogue", "tables", "--last-chunk", "prefix").startswith(
        "error: --last-chunk: 'prefix' counts a chunk's first splats: ")
    export = tmp_path / "exp"
    assert run_cli(capsys, "bundle", "export", world["bundle"], "--out", export)[0] == 0
    assert one_error_line(capsys, "bundle", "tables", export, "--fov", "0").startswith("error: --fov = 0.0: ")
    assert one_error_line(capsys, "bundle", "export", world["bundle"], "--out", tmp_path / "e2",
                          "--align", "3").startswith("error: --align: 3 ")


def test_simulate_refuses_a_path_rate_it_would_not_read(capsys, world):
    line = one_error_line(capsys, "simulate", world["bundle"], "--trace", "lumos-throughput-mid-11", "--path",
                          world["log"], "--method", "sort", "--slots", "2", "--path-rate", "3")
    assert line == "error: --path-rate: 3.0: only --path-format cameras reads it, not 'log'"


@pytest.mark.parametrize("extra, want", [
    (("--views", "-3"), "error: --views: -3: must be an integer in [1, 10000] (MAX_PATH_VIEWS)"),
    (("--width", "-7"), "error: --width"),
    (("--fov", "nan"), "error: --fov"),
])
def test_scene_make_checks_camera_options_without_a_path(capsys, tmp_path, extra, want):
    # no --orbit/--walk: the camera options were taken in silence (exit 0) before
    line = one_error_line(capsys, "scene", "make", "--splats", "1000", "--out", tmp_path / "s.ply", *extra)
    assert line.startswith(want), line
    assert not (tmp_path / "s.ply").exists()


def test_other_commands_name_the_option(capsys, tmp_path):
    assert one_error_line(capsys, "instance", "synth", "--objects", "-7", "-o", tmp_path / "i.json"
                          ).startswith("error: --objects = -7: ")
    assert one_error_line(capsys, "scene", "make", "--splats", "-7", "--out", tmp_path / "s.ply"
                          ).startswith("error: --splats: -7: ")
    assert one_error_line(capsys, "experiments", "--check-time", "-1", "--out", tmp_path / "e"
                          ).startswith("error: --check-time: -1.0: ")
    assert one_error_line(capsys, "experiments", "--window", "-1", "--out", tmp_path / "e"
                          ).startswith("error: --window: -1: ")
    assert one_error_line(capsys, "serve", tmp_path, "--port", "-7").startswith("error: --port: -7: ")


def test_serve_prints_nothing_but_its_error_when_refused(capsys, tmp_path):
    # the "serving ..." line came before the address check
    code, out, err = run_cli(capsys, "serve", tmp_path, "--host", "10.0.0.1")
    assert code == 2 and out == "" and err.startswith("error: --host: '10.0.0.1': only a loopback address")
    code, out, err = run_cli(capsys, "serve", tmp_path)
    assert code == 2 and out == "" and "index.json" in err
