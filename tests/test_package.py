"""The package surface: curated public API, the console script, errors and optional dependencies."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import prompose_grasp as pg
from prompose_grasp._optional import require
from prompose_grasp.cli import main


def test_public_api_names_exist():
    assert all(hasattr(pg, name) for name in pg.__all__)


def test_version_matches_installed_metadata():
    from importlib.metadata import version

    assert pg.__version__ == version("prompose-grasp")


def test_console_script_help_and_version():
    script = Path(sys.executable).parent / "prompose-grasp"
    out = subprocess.run([str(script), "--help"], capture_output=True, text=True, check=True).stdout
    assert "usage: prompose-grasp" in out
    assert "eval-nocs" in out
    out = subprocess.run([str(script), "--version"], capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"prompose-grasp {pg.__version__}"


def test_cli_without_command_prints_help(capsys):
    assert main([]) == 0
    assert "usage: prompose-grasp" in capsys.readouterr().out


def test_cli_reports_bad_input_with_exit_2(tmp_path, capsys):
    # An empty folder holds no result pickles: a one-line error and exit code 2, no traceback.
    assert main(["eval-nocs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("prompose-grasp eval-nocs: error:")
    assert "Traceback" not in err


def test_unknown_name_error_lists_the_choices():
    err = pg.UnknownNameError("robot", "ur6e", ["ur3e", "ur5e"])
    assert str(err) == "unknown robot 'ur6e'; known: ur3e, ur5e"
    assert isinstance(err, LookupError) and isinstance(err, pg.PromposeError)


def test_invalid_input_is_a_value_error():
    assert issubclass(pg.InvalidInputError, ValueError)


def test_require_names_the_extra_when_missing():
    with pytest.raises(pg.MissingDependencyError, match=r"pip install 'prompose-grasp\[ur\]'"):
        require("surely_not_an_installed_module_xyz", extra="ur")
    assert require("json", extra="none").__name__ == "json"
