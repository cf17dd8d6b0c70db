"""Every ``kogei`` argument explains itself: a help text, the unit of a physical quantity, the default.

The test walks the real parser (:func:`app.cli.build_parser`), every subcommand and every nested
action, so an argument added without a help text, a quantity without its unit or an option whose
default is left unsaid fails here.  Units are checked against :data:`UNITS`, which names every
quantity argument and the unit its help must state; every ``float`` option must be listed there.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]

_MM = r"\bmm\b"
_DEG = r"\b(deg|degrees)\b"
_S = r"\bseconds\b"
_PX = r"\b(px|pixels)\b"
_FRACTION = r"\b(fraction|relative)\b"
_KELVIN = r"\b(kelvin|K)\b"

#: (command path, option) -> the unit its help must state.  Every float option must be here.
UNITS: dict[tuple[str, str], str] = {
    ("mock", "--time-scale"): _S,
    ("mock place", "--timeout"): _S,
    ("mock shoot", "--timeout"): _S,
    ("capture", "--steps"): r"per revolution",
    ("capture", "--camera-angles"): _DEG,
    ("capture", "--sphere-radius"): _MM,
    ("capture", "--brackets"): _S,
    ("capture", "--steps-per-degree"): r"steps per degree",
    ("capture", "--speed"): r"\bdeg/s\b",
    ("capture", "--exposure-us"): r"(microseconds|µs)",
    ("capture", "--camera-timeout"): _S,
    ("capture", "--hotfolder-stable"): _S,
    ("capture", "--reconnect-timeout"): _S,
    ("calibrate", "--sphere-radius"): _MM,
    ("calibrate", "--sphere-height"): _MM,
    ("calibrate", "--focal-mm"): _MM,
    ("calibrate", "--sensor-mm"): _MM,
    ("calibrate", "--max-rms"): _PX,
    ("calibrate", "--lamp-spectrum"): _KELVIN,
    ("project", "--max-view-deg"): _DEG,
    ("project", "--edge-margin"): _PX,
    ("fit-materials", "--model-error"): _FRACTION,
    ("chart", "--inset"): _FRACTION,
    ("chart", "--trim"): _FRACTION,
    ("chart", "--chart-corners"): _PX,
    ("spectral estimate", "--noise"): _FRACTION,
    ("spectral estimate", "--light"): _KELVIN,
    ("spectral estimate", "--second-light"): r"as --light",
    ("spectral estimate", "--chart-corners"): _PX,
    ("spectral at", "x"): _PX,
    ("spectral at", "y"): _PX,
    ("identify", "--light-deg"): _DEG,
    ("identify", "--noise"): _FRACTION,
    ("identify", "--model-error"): _FRACTION,
    ("identify", "--min-level"): _FRACTION,
    ("cloth fit", "--pixels"): _PX,
    ("probe", "--sphere-radius"): _MM,
    ("probe", "--sphere-reflectance"): _FRACTION,
    ("probe", "--f-number"): r"\baperture\b",
    ("probe", "--camera-mask"): _DEG,
    ("probe", "--back-mask"): _DEG,
    ("probe", "--light"): _KELVIN,
    ("render", "--eye"): _MM,
    ("render", "--target"): _MM,
    ("render", "--up"): r"\bunitless\b",
    ("render", "--light"): _MM,
    ("render", "--illuminant"): _KELVIN,
    ("render", "--fov"): _DEG,
    ("render", "--size"): _PX,
    ("render", "--weave-angle"): _DEG,
    ("demo", "--size"): _PX,
    ("batch", "--workers"): r"\bprocesses\b",
}


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, action, the parser holding it) for every action of every (sub)parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, (*path, name))
        elif not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            yield " ".join(path), action, parser


def _name(action: argparse.Action) -> str:
    return action.option_strings[-1] if action.option_strings else action.dest


def _help(action: argparse.Action, parser: argparse.ArgumentParser) -> str:
    """The help as ``--help`` prints it (``%(default)s`` expanded)."""
    return parser._get_formatter()._expand_help(action) if action.help else ""


ACTIONS = list(_walk(build_parser()))


def _states_default(action: argparse.Action, text: str) -> bool:
    """The help says what the default is, and the value it states is the real one."""
    if "default" not in text.lower():
        return False
    v = action.default
    if v is None:
        return True
    shown = {str(v)} | ({f"{v:g}"} if isinstance(v, float) else set())
    return any(re.search(rf"default:? {re.escape(s)}(?![\d.])", text)                # "(default 30)"
               or re.search(rf"\b{re.escape(s)}\b[^;]{{0,40}}\bdefault\)", text)    # "demosaic (full resolution, default)"
               for s in shown)


def test_the_walk_sees_every_subcommand_and_option():
    commands = {path.split(" ")[0] for path, _, _ in ACTIONS}
    assert commands == set(COMMANDS)
    assert len(ACTIONS) > 150
    names = {(path, _name(a)) for path, a, _ in ACTIONS}
    assert not set(UNITS) - names, f"UNITS names options the parser does not have: {set(UNITS) - names}"


def test_every_argument_has_a_help_text():
    missing = [f"kogei {path} {_name(a)}" for path, a, _ in ACTIONS if not (a.help or "").strip()]
    assert not missing, "arguments without a help text: " + ", ".join(missing)


def test_every_default_is_stated_and_true():
    """Options with a value default, choices or a physical quantity say their default in the help."""
    unsaid = []
    for path, a, parser in ACTIONS:
        if a.required or not a.option_strings or a.nargs == 0 or a.default == []:
            continue
        needs = a.default is not None or a.choices is not None or (path, _name(a)) in UNITS
        if needs and not _states_default(a, _help(a, parser)):
            unsaid.append(f"kogei {path} {_name(a)} (default {a.default!r})")
    assert not unsaid, "defaults not stated (or stated wrong): " + "; ".join(unsaid)


def test_every_quantity_states_its_unit():
    floats = [f"kogei {path} {_name(a)}" for path, a, _ in ACTIONS if a.type is float and (path, _name(a)) not in UNITS]
    assert not floats, "float options missing from UNITS (add them with their unit): " + ", ".join(floats)
    by_name = {(path, _name(a)): (a, parser) for path, a, parser in ACTIONS}
    wrong = [f"kogei {path} {opt}: expected /{unit}/ in {_help(*by_name[(path, opt)])!r}"
             for (path, opt), unit in UNITS.items() if not re.search(unit, _help(*by_name[(path, opt)]))]
    assert not wrong, "\n".join(wrong)


def test_fit_materials_model_error_is_the_batch_one():
    from app.batch.steps import _materials_params
    from app.workflows.object_materials import FIT_MODEL_ERROR

    fit = next(a for path, a, _ in ACTIONS if path == "fit-materials" and _name(a) == "--model-error")
    options = argparse.Namespace(chart="classic24", preset="standard")
    assert fit.default == FIT_MODEL_ERROR == _materials_params(options)["on_mesh"]["model_error"]


def test_top_level_help_lists_the_commands_in_workflow_order(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    listed = [c for c in re.findall(r"^    ([a-z-]+)", out, flags=re.M) if c in COMMANDS]
    assert listed == list(COMMANDS)
    workflow = ["mock", "capture", "calibrate", "process", "render", "export", "report", "batch", "gui", "demo"]
    assert [c for c in listed if c in workflow] == workflow
    assert "order a session's work runs" in " ".join(out.split())


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    import tomllib

    expected = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out.strip() == f"kogei {expected}"


def test_output_into_a_pipe_closed_early_ends_without_a_traceback():
    """``kogei materials gold | head -0``: the reader is gone before kogei writes; no BrokenPipeError traceback."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    read_end, write_end = os.pipe()
    os.close(read_end)                # closed before the child writes a byte: every write fails (EPIPE)
    try:
        proc = subprocess.run([sys.executable, "-m", "app.cli", "materials", "gold"], cwd=ROOT, env=env,
                              stdout=write_end, stderr=subprocess.PIPE, timeout=120)
    finally:
        os.close(write_end)
    err = proc.stderr.decode()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode == 1, (proc.returncode, err)


def test_capture_states_the_device_defaults_the_drivers_get(tmp_path):
    """The defaults ``kogei capture --help`` states are the ones the turntable and profiler are built with."""
    from app.capture.devices import build_devices

    by_name = {_name(a): (a, parser) for path, a, parser in ACTIONS if path == "capture"}
    devices = build_devices({"turntable": {"port": str(tmp_path / "tt")}, "profiler": {"port": str(tmp_path / "pr")}},
                            None)
    for option, value in (("--steps-per-degree", f"{devices.turntable.steps_per_degree:.4g}"),
                          ("--speed", f"{devices.turntable.speed_deg_s:g}"),
                          ("--exposure-us", str(devices.profiler.exposure_us))):
        assert f"default {value}" in _help(*by_name[option]), (option, value)


def test_a_ctrl_c_wrapped_by_a_module_import_exits_130_without_a_traceback(monkeypatch, capsys):
    # a Ctrl-C during Open3D's first import reaches the command as ImportError caused by KeyboardInterrupt
    import app.cli.devices as devices

    def run(_args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(devices, "run", run)
    assert main(["devices"]) == 130
    assert capsys.readouterr().err.strip() == "kogei devices: interrupted"
