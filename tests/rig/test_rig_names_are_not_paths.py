"""Names are not paths (docs/rig.md "Names"): every name of a rig file that may become a file name in
the rig's folder (a bus's socket ``NAME.sock``, a drive's ``NAME.params.json`` and ``NAME.eds``, an IDX's
``NAME.store``) follows one rule, checked by the rig-file validator (exit 2, one line naming the file,
section and key), and no file is created or removed outside the rig's own folder."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus.transport.unix_file import UNIX_PATH_MAX, SocketPathError, bind_unix, remove_unix
from gatewaylab.common.errors import ConfigError
from gatewaylab.plugin import NAME_MAX, DeviceKind, Key, name_problem, state_file
from gatewaylab.rig.config import parse_rig

BAD_NAMES = ["../somedir/victim", "a/b", "/etc/x", "..", ".", ".hidden", "-x", "@x", "can 0", "can0 ", "a\nb",
             "a\x00b", "caf\u00e9", "a" * (NAME_MAX + 1), "C:\\x", "a*b"]
GOOD_NAMES = ["can0", "a", "a" * NAME_MAX, "drive2@can0", "x.y-z_1", "0", "_x", "axis..2"]


def gl_run(rig: Path, tmpdir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """`gatewaylab run RIG` as a user starts it, with its temporary folder under ``tmpdir``."""
    return subprocess.run([sys.executable, "-m", "gatewaylab", "run", str(rig), *args], capture_output=True,
                          text=True, timeout=60, env={**os.environ, "TMPDIR": str(tmpdir)})


def test_a_bus_named_to_climb_out_of_the_folder_is_refused_and_the_users_file_survives(tmp_path: Path) -> None:
    """The reported case: ``[[bus]] name = "../somedir/victim"`` made the rig bind its socket at
    ``TMPDIR/gatewaylab-XXXX/../somedir/victim.sock`` and delete the user's file of that name at exit.
    Now the validator refuses the name before anything exists: exit 2, one line naming section and key."""
    tmpdir = tmp_path / "tmp"
    victims = tmp_path / "somedir"
    tmpdir.mkdir()
    victims.mkdir()
    victim = victims / "victim.sock"
    victim.write_text("the user's file")
    rig = tmp_path / "rig.toml"
    # the state folder is tmpdir/gatewaylab-XXXX: two levels up is tmp_path, where somedir is
    rig.write_text('[[bus]]\nname = "../../somedir/victim"\n')
    out = gl_run(rig, tmpdir)
    assert out.returncode == 2, out.stderr
    err = out.stderr.strip()
    assert err == (f"gatewaylab: {rig} [[bus]] #1: name = '../../somedir/victim' has '/' in it: names must be "
                   f"1..{NAME_MAX} characters of A-Z a-z 0-9 _ . @ -, not starting with . @ or - (a name "
                   f"becomes a file name in the rig's folder)")
    assert victim.read_text() == "the user's file"
    assert sorted(p.name for p in victims.iterdir()) == ["victim.sock"]
    assert list(tmpdir.iterdir()) == []          # refused before the rig made its folder


@pytest.mark.parametrize("name", BAD_NAMES)
@pytest.mark.parametrize("section", ["bus", "drive", "maxon_idx"])
def test_bad_names_are_refused_by_the_validator_in_one_line(name: str, section: str) -> None:
    """docs/rig.md "Names": a name with ``/``, spaces, ``..`` as a whole, a leading ``.`` ``-`` ``@``,
    anything outside A-Z a-z 0-9 _ . @ -, or longer than NAME_MAX: one ConfigError line
    ``FILE [[section]] #n: name = '...' problem``, for buses and for every device kind."""
    data: dict[str, Any] = {"bus": [{"name": "can0"}]}
    label = section
    if section == "bus":
        data["bus"].append({"name": name})
        number = 2
    elif section == "drive":
        data["drive"] = [{"bus": "can0", "node_id": 2, "serial": 0x1002, "name": name}]
        number = 1
    else:
        data["device"] = [{"kind": "maxon_idx", "bus": "can0", "name": name}]
        label, number = "device", 1
    with pytest.raises(ConfigError) as caught:
        parse_rig(data, "my.toml")
    message = str(caught.value)
    assert message.startswith(f"my.toml [[{label}]] #{number}: name = {name!r} ")
    assert "\n" not in message and "names must be" in message


@pytest.mark.parametrize("name", GOOD_NAMES)
def test_good_names_are_accepted_for_buses_and_devices(name: str) -> None:
    config = parse_rig({"bus": [{"name": name}], "drive": [{"bus": name, "node_id": 2, "serial": 1, "name": name}]})
    assert config.buses[0].name == name


def test_a_plugin_kinds_name_goes_through_the_same_validator() -> None:
    """docs/devices/writing-a-device.md: a kind outside gatewaylab declares ``name = Key(str)`` and gets
    the name rule with it (DeviceKind.validate, which the rig calls for every section); ``Key(name=True)``
    applies it to any other key of its that becomes a file name."""
    kind = DeviceKind("echo_box", lambda rig, cfg: None,  # type: ignore[arg-type,return-value]
                      {"name": Key(str, "echo"), "log": Key(str, name=True)})
    assert kind.validate({"name": "echo1", "log": "echo1-log"}, "w")["name"] == "echo1"
    for cfg, key in [({"name": "../../etc/passwd"}, "name"), ({"log": "../x"}, "log")]:
        with pytest.raises(ConfigError, match=rf"^w: {key} = '\.\./"):
            kind.validate(cfg, "w")


def test_a_default_name_made_too_long_asks_for_a_name() -> None:
    """A default made of other names (``bridge-BUS-INTERFACE``) follows the rule too."""
    bus = "b" * NAME_MAX
    with pytest.raises(ConfigError, match=r"^x.toml \[\[bridge\]\] #1: its default name 'bridge-b+-virtual' is "
                                          r"47 characters long .*give it a name = "):
        parse_rig({"bus": [{"name": bus}], "bridge": [{"bus": bus, "interface": "virtual"}]}, "x.toml")


def test_the_control_sockets_name_is_not_a_bus_name() -> None:
    """The rig's control socket is ``gatewaylab-control.sock`` in the same folder (docs/faults.md)."""
    with pytest.raises(ConfigError, match="taken by the rig's control socket"):
        parse_rig({"bus": [{"name": "gatewaylab-control"}]}, "x.toml")


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=40) | st.text(alphabet="./-@_aZ09 \\", max_size=40))
def test_whatever_the_validator_accepts_stays_in_the_folder(name: str) -> None:
    """Property: a bus name parse_rig accepts is a file name directly in the rig's folder whose socket
    path fits AF_UNIX with a TMPDIR of 49 characters; state_file agrees with the validator."""
    folder = Path("/" + "t" * 48) / "gatewaylab-12345678"     # under a TMPDIR "/ttt..." of 49 characters
    try:
        parse_rig({"bus": [{"name": name}]}, "fuzz.toml")
    except ConfigError as exc:
        assert "\n" not in str(exc)
        if name != "gatewaylab-control":
            assert name_problem(name) is not None
            with pytest.raises(ConfigError):
                state_file(folder, name, ".sock")
        return
    path = state_file(folder, name, ".sock")
    assert os.path.normpath(path) == str(path) and path.parent == folder and path.name == f"{name}.sock"
    assert len(os.fsencode(path)) <= UNIX_PATH_MAX


def test_state_file_refuses_a_link_out_of_the_folder(tmp_path: Path) -> None:
    """Defence in depth: a file the rig makes from a name is resolved first; a symbolic link in the
    folder that leads elsewhere is refused rather than followed."""
    folder = tmp_path / "state"
    folder.mkdir()
    outside = tmp_path / "outside.params.json"
    (folder / "drive2.params.json").symlink_to(outside)
    with pytest.raises(ConfigError, match="not a file inside the rig's folder"):
        state_file(folder, "drive2", ".params.json")
    assert state_file(folder, "drive3", ".params.json") == folder / "drive3.params.json"


def test_a_unix_endpoint_never_replaces_or_removes_a_file_that_is_not_its_socket(tmp_path: Path) -> None:
    """bind_unix replaces only a stale socket file; remove_unix removes only the socket it bound."""
    path = tmp_path / "can0.sock"
    path.write_text("data")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock, \
            pytest.raises(SocketPathError, match="not a socket"):
        bind_unix(sock, path)
    assert path.read_text() == "data"
    path.unlink()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as stale:
        stale.bind(str(path))                       # a socket left behind by a killed rig
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        bound = bind_unix(sock, path)
        path.unlink()
        path.write_text("a file of the user's, put there since")
        remove_unix(path, bound)
    assert path.read_text() == "a file of the user's, put there since"


def test_a_temporary_folder_too_long_for_unix_sockets_says_so(tmp_path: Path) -> None:
    """AF_UNIX paths are at most 107 bytes: a TMPDIR too long for the rig's sockets is one line naming
    TMPDIR and what to do (exit 1: the environment, not the rig file), and leaves no folder behind."""
    tmpdir = tmp_path / ("t" * max(1, 100 - len(str(tmp_path))))
    tmpdir.mkdir()
    rig = tmp_path / "rig.toml"
    rig.write_text('[[bus]]\nname = "can0"\n')
    out = gl_run(rig, tmpdir)
    assert out.returncode == 1, out.stderr
    err = out.stderr.strip()
    assert "\n" not in err and "Traceback" not in err
    assert f"TMPDIR {tmpdir}" in err and "at most 49 characters" in err and 'endpoint = "tcp"' in err
    assert list(tmpdir.iterdir()) == []
