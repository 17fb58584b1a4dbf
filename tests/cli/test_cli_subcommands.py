"""The sub-command hook of ``gatewaylab`` (cli/main.py ``EXTRA_SUBCOMMANDS``): issue 30 'The map without
gaps' -- "make a broken subcommand module an error, not a missing command"."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gatewaylab.cli import main as cli_main

#: A program that runs ``gatewaylab rig`` with one more sub-command module in the hook.
PROGRAM = """
import sys
from gatewaylab.cli import main as cli
cli.EXTRA_SUBCOMMANDS = (*cli.EXTRA_SUBCOMMANDS, sys.argv[1])
sys.exit(cli.main(["rig"]))
"""


def _gatewaylab_with(module: str, folder: Path) -> subprocess.CompletedProcess[str]:
    """``gatewaylab rig`` in another process, the hook extended by ``module`` (found in ``folder``)."""
    return subprocess.run([sys.executable, "-c", PROGRAM, module], cwd=folder, capture_output=True, text=True,
                          timeout=120, env={"PYTHONPATH": str(folder), "PATH": "/usr/bin:/bin"}, check=False)


def test_every_shipped_subcommand_module_loads() -> None:
    """Every module of the hook loads and registers its command: the parser knows each of them."""
    parser = cli_main.build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    assert commands is not None
    for module_name in cli_main.EXTRA_SUBCOMMANDS:
        assert module_name.rsplit(".", 1)[1] in commands, module_name


def test_a_subcommand_module_that_does_not_import_stops_gatewaylab(tmp_path: Path) -> None:
    """A sub-command module whose import fails (here: a dependency that is not installed) is an error
    that names the module and the cause, with exit code 1 -- not a command missing from the parser
    while everything else runs (the old hook skipped it and ``gatewaylab rig`` succeeded)."""
    (tmp_path / "gl_broken_cmd.py").write_text(
        "import gl_dependency_not_installed\n\n\ndef add_subcommand(subparsers):\n    pass\n")
    done = _gatewaylab_with("gl_broken_cmd", tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "gl_broken_cmd" in done.stderr and "gl_dependency_not_installed" in done.stderr
    assert done.stdout == ""


def test_a_subcommand_module_without_add_subcommand_stops_gatewaylab(tmp_path: Path) -> None:
    """A module in the hook without ``add_subcommand(subparsers)`` is the same error."""
    (tmp_path / "gl_empty_cmd.py").write_text('"""No add_subcommand here."""\n')
    done = _gatewaylab_with("gl_empty_cmd", tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "gl_empty_cmd" in done.stderr and "add_subcommand" in done.stderr


def test_build_parser_raises_for_a_broken_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """In process, ``build_parser`` raises SubcommandError (a GatewaylabError) for the broken module."""
    (tmp_path / "gl_raising_cmd.py").write_text("raise ImportError('broken on purpose')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(cli_main, "EXTRA_SUBCOMMANDS", (*cli_main.EXTRA_SUBCOMMANDS, "gl_raising_cmd"))
    with pytest.raises(cli_main.SubcommandError, match="broken on purpose"):
        cli_main.build_parser()
