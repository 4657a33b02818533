# install.sh systemd/uninstall in a staging root: layout, owners and modes, idempotence, refusals.
from __future__ import annotations

import grp
import hashlib
import inspect
import json
import os
import re
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from sim.arduino_emulator import ArduinoEmulator
from sim.rplidar_emulator import RplidarEmulator
from tests.support.deploy import INSTALL_SH, SYSTEMD_DIR
from tests.support.deploy.machine import FAKE_SYSTEMCTL, Machine
from tests.support.deploy.machine import available as machine_available
from tests.support.deploy.wheels import Wheels, add_ros2_extra, wheels
from tests.support.net import free_port
from tests.support.wait import wait_for

CONFIG_FILES = {
    "/etc/arbiterd": "root:arbiterd 0750",
    "/etc/arbiterd/arbiterd.env": "root:root 0644",
    "/etc/arbiterd/arbiterd.toml": "root:arbiterd 0640",
    "/etc/arbiterd/token": "root:arbiterd 0640",
}
SYSTEM_FILES = {
    "/etc/systemd/system/arbiterd.service": "root:root 0644",
    "/etc/systemd/system/robot.target": "root:root 0644",
    "/etc/udev/rules.d/99-rplidar.rules": "root:root 0644",
    "/etc/udev/rules.d/99-arduino.rules": "root:root 0644",
    "/opt/arbiterd": "root:root 0755",
    "/opt/arbiterd/current": "root:root link",
    "/opt/arbiterd/history": "root:root 0644",
    "/opt/arbiterd/releases": "root:root 0755",
    "/usr/local/bin/arbiterd": "root:root link",
}


# every install builds a release venv: about 25 s on a quiet 2-core box, minutes on a busy one
pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Wheels:
    return wheels(tmp_path_factory)


def install_sh(*args: str, wheelhouse: Path | None = None, user: bool = False,
               env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    extra = env or {}
    env = {k: v for k, v in os.environ.items() if not k.startswith("ARBITERD_")}
    env.update(extra)
    if wheelhouse is not None:
        env["ARBITERD_PIP_ARGS"] = f"--no-index --find-links {wheelhouse}"
    script, cwd = INSTALL_SH, None
    cmd = ["bash", str(script), *args]
    if user and os.geteuid() == 0:  # run as an ordinary user, as someone forgetting sudo would
        cwd = Path(tempfile.mkdtemp(prefix="arbiterd-user-"))  # a copy that user can read
        cwd.chmod(0o755)
        script = Path(shutil.copy(INSTALL_SH, cwd))
        cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups",
               "bash", str(script), *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300,
                              check=False, stdin=subprocess.DEVNULL, cwd=cwd)
    finally:
        if cwd is not None:
            shutil.rmtree(cwd)


def install(root: Path, built: Wheels, *flags: str) -> subprocess.CompletedProcess[str]:
    result = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel), *flags,
                        wheelhouse=built.wheelhouse)
    assert result.returncode == 0, result.stdout + result.stderr
    return result


def manifest(root: Path) -> dict[str, str]:
    lines = (root / ".arbiterd-manifest").read_text().splitlines()
    return dict(line.split("\t", 1) for line in lines)


def actions(root: Path) -> list[str]:
    return (root / ".arbiterd-actions").read_text().splitlines()


def release_of(root: Path) -> str:
    return os.readlink(root / "opt/arbiterd/current").removeprefix("releases/")


def snapshot(root: Path) -> dict[str, tuple[int, int, int, str]]:
    """Every path below root with its mode, size, mtime and link target."""
    snap = {}
    for path in sorted(root.rglob("*")):
        if path.name == ".arbiterd-actions":
            continue
        st = path.lstat()
        target = os.readlink(path) if path.is_symlink() else ""
        snap[str(path.relative_to(root))] = (st.st_mode, st.st_size, st.st_mtime_ns, target)
    return snap


def changed_paths(before: dict[str, tuple[int, int, int, str]],
                  after: dict[str, tuple[int, int, int, str]]) -> list[str]:
    """The paths added, removed or changed between two snapshots, named in a short list."""
    added = sorted(after.keys() - before.keys())
    removed = sorted(before.keys() - after.keys())
    changed = sorted(k for k in before.keys() & after.keys() if before[k] != after[k])
    if not (added or removed or changed):
        return []
    return ([f"+ {k}" for k in added[:10]] + [f"- {k}" for k in removed[:10]]
            + [f"~ {k}: {before[k]} -> {after[k]}" for k in changed[:10]]
            + [f"({len(added)} added, {len(removed)} removed, {len(changed)} changed)"])


def disk_mode(path: Path) -> str:
    return f"{stat.S_IMODE(path.lstat().st_mode):04o}"


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory,
           built: Wheels) -> Iterator[tuple[Path, subprocess.CompletedProcess[str]]]:
    root = tmp_path_factory.mktemp("staging") / "root"
    yield root, install(root, built)


def test_lays_out_exactly_the_service_files(staged: tuple[Path, subprocess.CompletedProcess[str]],
                                            built: Wheels) -> None:
    root, _ = staged
    release_dir = f"/opt/arbiterd/releases/{release_of(root)}"
    expected = {**CONFIG_FILES, **SYSTEM_FILES, release_dir: "root:root 0755"}
    assert manifest(root) == expected
    for path, owner_mode in expected.items():
        mode = owner_mode.split()[1]
        if mode != "link":
            assert disk_mode(root / path.lstrip("/")) == mode, path
    top = {str(p.relative_to(root)) for p in root.iterdir()}
    assert top == {".arbiterd-manifest", ".arbiterd-actions", "etc", "opt", "usr"}
    for unit in ("arbiterd.service", "robot.target"):
        placed = root / "etc/systemd/system" / unit
        assert placed.read_bytes() == (SYSTEMD_DIR / unit).read_bytes()
    for name in ("99-rplidar.rules", "99-arduino.rules"):
        rules = root / "etc/udev/rules.d" / name
        assert rules.read_bytes() == (SYSTEMD_DIR / name).read_bytes()


def test_release_venv_runs_the_installed_package(
        staged: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    root, _ = staged
    venv = root / "opt/arbiterd/current/venv"
    assert "include-system-site-packages = true" in (venv / "pyvenv.cfg").read_text()
    if Path("/usr/bin/python3").exists():  # the system's Python, which sees apt's GPIO modules
        assert "home = /usr/bin\n" in (venv / "pyvenv.cfg").read_text()
    result = subprocess.run([str(venv / "bin/arbiterd"), "--version"], capture_output=True,
                            text=True, timeout=60, check=False)
    assert result.returncode == 0 and result.stdout.startswith("arbiterd "), result.stderr
    console = subprocess.run(  # the web console's files are inside the installed wheel
        [str(venv / "bin/python"), "-c",
         "from daemon.components.console.component import FILES, load\n"
         "print(sum(len(load(name).body) for name in FILES))"],
        capture_output=True, text=True, timeout=60, check=False)
    assert console.returncode == 0 and int(console.stdout) > 10_000, console.stderr
    shipped = root / "opt/arbiterd/current"
    assert (shipped / "install.sh").read_bytes() == INSTALL_SH.read_bytes()
    assert (shipped / "systemd/arbiterd.service").is_file()
    # every user's PATH has the current release's command (a relative link: valid in the root)
    on_path = shutil.which("arbiterd", path=str(root / "usr/local/bin"))
    assert on_path and Path(on_path).resolve() == (venv / "bin/arbiterd").resolve()
    assert os.readlink(root / "usr/local/bin/arbiterd") == \
        "../../../opt/arbiterd/current/venv/bin/arbiterd"


def test_config_token_and_mode(staged: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    root, first = staged
    token = (root / "etc/arbiterd/token").read_text().strip()
    assert len(token) >= 32
    assert first.stdout.count(token) == 1, "the token is printed exactly once"
    config = (root / "etc/arbiterd/arbiterd.toml").read_text()
    assert 'token_file = "/etc/arbiterd/token"' in config
    assert 'type = "serial"' in config and 'port = "/dev/arduino"' in config  # the udev name
    assert "ARBITERD_ARGS=--sim\n" in (root / "etc/arbiterd/arbiterd.env").read_text()
    recorded = actions(root)
    assert any(a.startswith("ensure system user arbiterd") and "gpio dialout" in a
               for a in recorded)
    assert "verify arbiterd is in groups: dialout" in recorded
    assert "systemctl daemon-reload" in recorded
    assert "systemctl enable arbiterd.service robot.target" in recorded
    assert "systemctl restart arbiterd.service" in recorded


def test_second_run_changes_nothing(staged: tuple[Path, subprocess.CompletedProcess[str]],
                                    built: Wheels) -> None:
    root, _ = staged
    before = snapshot(root)
    again = install(root, built)
    changes = changed_paths(before, snapshot(root))
    assert not changes, "\n".join([*changes, again.stdout])
    token = (root / "etc/arbiterd/token").read_text().strip()
    assert token not in again.stdout
    recorded = actions(root)
    assert "systemctl daemon-reload" not in recorded
    assert "systemctl restart arbiterd.service" not in recorded
    assert "systemctl start arbiterd.service" in recorded


def test_units_verify_against_the_staged_exec_start(
        staged: tuple[Path, subprocess.CompletedProcess[str]], tmp_path: Path) -> None:
    root, _ = staged
    check_root = tmp_path / "verify-root"
    shutil.copytree(Path("/usr/lib/systemd/system"), check_root / "usr/lib/systemd/system",
                    symlinks=True)
    shutil.copytree(root / "etc/systemd", check_root / "etc/systemd")
    # the installed releases (ExecStart included), hard-linked: verify --root resolves every
    # path, symlinks too, inside the root
    shutil.copytree(root / "opt", check_root / "opt", symlinks=True, copy_function=os.link)
    exe = shutil.which("systemd-analyze")
    assert exe
    result = subprocess.run(
        [exe, "verify", "--man=no", "--generators=no", f"--root={check_root}",
         "arbiterd.service", "robot.target"],
        capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0 and not result.stderr.strip(), result.stderr


def test_pigpio_hardware_then_existing_config_is_kept(tmp_path: Path, built: Wheels) -> None:
    root = tmp_path / "root"
    install(root, built, "--hardware", "--driver", "pigpio")
    config = (root / "etc/arbiterd/arbiterd.toml").read_text()
    assert 'type = "pigpio"' in config
    assert "ARBITERD_ARGS=\n" in (root / "etc/arbiterd/arbiterd.env").read_text()
    for dropin in ("arbiterd.service.d", "robot.target.d"):
        placed = root / "etc/systemd/system" / dropin / "pigpiod.conf"
        assert placed.read_bytes() == (SYSTEMD_DIR / "pigpiod.conf").read_bytes()
    assert "apt-get install python3-venv pigpiod" in actions(root)
    assert "systemctl enable --now pigpiod.service" in actions(root)

    (root / "etc/arbiterd/arbiterd.toml").write_text(config + "# edited by the user\n")
    rerun = install(root, built, "--sim", "--driver", "serial")
    assert (root / "etc/arbiterd/arbiterd.toml").read_text() == config + "# edited by the user\n"
    assert "--driver serial ignored" in rerun.stderr
    assert "ARBITERD_ARGS=--sim\n" in (root / "etc/arbiterd/arbiterd.env").read_text()
    assert not (root / "etc/systemd/system/arbiterd.service.d").exists()
    assert "systemctl restart arbiterd.service" in actions(root)


def test_uninstall_keeps_config_unless_purge(tmp_path: Path, built: Wheels) -> None:
    root = tmp_path / "root"
    install(root, built)
    kept = {p: (root / p.lstrip("/")).read_bytes() for p in CONFIG_FILES if p != "/etc/arbiterd"}
    removed = install_sh("uninstall", "--root", str(root))
    assert removed.returncode == 0, removed.stderr
    assert manifest(root) == CONFIG_FILES
    left = {"/" + str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}
    assert left == set(kept) | {"/.arbiterd-manifest", "/.arbiterd-actions"}
    assert all((root / p.lstrip("/")).read_bytes() == data for p, data in kept.items())
    assert "systemctl disable --now arbiterd.service robot.target" in actions(root)
    assert not (root / "opt").exists() or not any((root / "opt").iterdir())

    purged = install_sh("uninstall", "--purge", "--root", str(root))
    assert purged.returncode == 0, purged.stderr
    assert {p.name for p in root.rglob("*") if p.is_file()} == {".arbiterd-actions"}
    assert "userdel arbiterd" in actions(root)


def test_dry_run_prints_actions_and_changes_nothing(tmp_path: Path, built: Wheels) -> None:
    root = tmp_path / "root"
    result = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel), "--dry-run")
    assert result.returncode == 0, result.stderr
    assert not root.exists()
    out = result.stdout
    assert "[dry-run] install -D -m 0640" in out and "etc/arbiterd/token" in out
    assert f"[dry-run] install -D -m 0644 {SYSTEMD_DIR}/arbiterd.service" in out
    assert "-m venv --system-site-packages" in out
    assert "[dry-run] ln -sfn releases/" in out


@pytest.mark.parametrize(("flags", "with_ros2"), [((), True), (("--no-ros2",), False)])
def test_a_later_release_keeps_the_ros2_face_unless_told(tmp_path: Path, built: Wheels,
                                                          flags: tuple[str, ...],
                                                          with_ros2: bool) -> None:
    root = tmp_path / "root"
    current = root / "opt/arbiterd/releases/0.1.0-deployed"  # what deploy-pi.sh names it
    current.mkdir(parents=True)
    (current / ".ros2").touch()
    (root / "opt/arbiterd/current").symlink_to("releases/0.1.0-deployed")
    result = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel),
                        "--release", "0.1.1-next", "--dry-run", *flags)
    assert result.returncode == 0, result.stderr
    pip_line = next(line for line in result.stdout.splitlines() if " pip install " in line
                    and str(built.wheel) in line)
    assert (shlex.split(pip_line)[-1] == f"{built.wheel}[ros2]") == with_ros2, pip_line
    assert ("CYCLONEDDS_HOME=" in pip_line) == with_ros2, pip_line
    assert ("cyclonedds-dev" in result.stdout) == with_ros2, result.stdout


def test_staging_dry_run_never_names_a_path_outside_the_root(tmp_path: Path,
                                                             built: Wheels) -> None:
    root = tmp_path / "root"
    result = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel), "--dry-run",
                        "--hardware", "--driver", "pigpio")
    assert result.returncode == 0, result.stderr
    system_dirs = ("/etc", "/opt", "/var", "/usr")
    for line in result.stdout.splitlines():
        if line.startswith("[dry-run]"):  # the arguments (the command may be /usr/bin/...)
            assert not [w for w in line.split()[2:] if w.startswith(system_dirs)], line


def test_dry_run_on_this_machine_prints_the_real_actions_and_changes_nothing() -> None:
    watched = [Path(p) for p in ("/opt/arbiterd", "/etc/arbiterd", "/var/lib/arbiterd",
                                 "/etc/systemd/system/arbiterd.service",
                                 "/etc/udev/rules.d/99-rplidar.rules")]
    before = {p: p.exists() for p in watched}
    result = install_sh("systemd", "--dry-run")
    assert result.returncode == 0, result.stderr
    assert {p: p.exists() for p in watched} == before
    out = result.stdout
    assert (f"[dry-run] install -D -m 0644 {SYSTEMD_DIR}/arbiterd.service "
            "/etc/systemd/system/arbiterd.service") in out
    assert "[dry-run] install -D -m 0644" in out and " /etc/udev/rules.d/99-rplidar.rules" in out
    assert "-m venv --system-site-packages /opt/arbiterd/releases/" in out
    assert "[dry-run] systemctl daemon-reload" in out
    assert "[dry-run] systemctl restart arbiterd.service" in out


@pytest.mark.parametrize("command", ["systemd", "uninstall", "rollback"])
def test_refuses_a_normal_user_where_root_is_needed(tmp_path: Path, command: str) -> None:
    result = install_sh(command, user=True)
    assert result.returncode == 1
    assert f"'./install.sh {command}' changes the system and must run as root" in result.stderr
    assert f"sudo ./install.sh {command}" in result.stderr


def test_bad_options_are_usage_errors() -> None:
    for args, message in [
        (["systemd", "--driver", "stepper"], "--driver stepper: not one of: mock l298n"),
        (["systemd", "--keep", "1"], "--keep 1: need a number >= 2"),
        (["systemd", "--frobnicate"], "unknown option: --frobnicate"),
        (["launch"], "unknown command 'launch'"),
    ]:
        result = install_sh(*args)
        assert result.returncode == 2, args
        assert message in result.stderr


# -- the README's robot steps, as written, on this machine in a private mount namespace --------

REPO_DIR = INSTALL_SH.parent
README = REPO_DIR / "README.md"


def readme_robot_steps(block: int = 0) -> list[str]:
    """The commands of an ``sh`` block (the first: the install; the second: the optional ROS 2
    face) under README's "On the robot", comments dropped."""
    section = README.read_text().split("## On the robot", 1)[1].split("\n## ", 1)[0]
    text = section.split("```sh\n")[1 + block].split("```", 1)[0]
    return [line.split("  #", 1)[0].strip() for line in text.splitlines() if line.strip()]


def set_key(text: str, section: str, key: str, value: str) -> str:
    """The user's edit: ``key = value`` in ``[section]``, replacing a (commented) assignment."""
    lines, current = text.splitlines(), None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith("[") and stripped.endswith("]"):
            current = stripped[1:-1]
        elif current == section and stripped.lstrip("# ").startswith(f"{key} ="):
            lines[i] = f"{key} = {value}"
            return "\n".join(lines) + "\n"
    raise AssertionError(f"no {key} in [{section}] of the installed config")


EDITOR = """import json, os, sys
{set_key}
path = sys.argv[-1]
text = open(path).read()
calls = {edits!r} + ".calls"
call = int(open(calls).read()) if os.path.exists(calls) else 0
open(calls, "w").write(str(call + 1))
for section, key, value in json.load(open({edits!r}))[call]:
    text = set_key(text, section, key, value)
open(path, "w").write(text)
"""


def device_for(link: Path) -> None:
    """What the udev rules do for a real board: the device node group dialout, mode 0660."""
    node = os.path.realpath(link)
    os.chown(node, 0, grp.getgrnam("dialout").gr_gid)
    os.chmod(node, 0o660)


def step_script(steps: list[str], out: Path) -> str:
    """Bash running each step in order (output and exit status kept per step), stopping at the
    first failure; the service is stopped however it ends."""
    lines = ["trap 'systemctl stop robot.target >/dev/null 2>&1 || true' EXIT", "set +e"]
    for i, step in enumerate(steps):
        lines += [f"bash -c {shlex.quote(step)} >{out}/step{i}.out 2>&1",
                  f"echo $? >{out}/step{i}.rc", f'[ "$(cat {out}/step{i}.rc)" = 0 ] || exit 0']
    return "\n".join(lines)


@pytest.mark.timeout(600)
def test_readme_robot_steps_as_written_end_in_a_hardware_service(tmp_path: Path,
                                                                 built: Wheels) -> None:
    if why := machine_available():
        pytest.skip(f"the README robot steps run in a private mount namespace: {why}")
    steps, ros2_steps = readme_robot_steps(), readme_robot_steps(1)
    assert steps[0].startswith("sudo ./install.sh systemd --hardware --driver serial"), steps
    assert ros2_steps[0] == "sudo ./install.sh systemd --ros2", ros2_steps
    steps += ros2_steps
    add_ros2_extra(built)
    machine = Machine(tmp_path / "machine")
    out = tmp_path / "out"
    out.mkdir()
    devices = Path(tempfile.mkdtemp(prefix="arbiterd-dev-"))  # the service user reaches it
    devices.chmod(0o755)
    http_port, ws_port = free_port(), free_port()
    # the board's emulator is a thread of this (loaded) test process: a reply may take longer
    # than a real board's 0.25 s allowance while the CI box is busy
    edits = [("driver.serial", "port", f'"{devices / "arduino"}"'),
             ("driver.serial", "timeout_s", "2.0"),
             ("lidar", "port", f'"{devices / "rplidar"}"'),
             ("http", "host", '"127.0.0.1"'), ("http", "port", str(http_port)),
             ("rosbridge", "host", '"127.0.0.1"'), ("rosbridge", "port", str(ws_port))]
    ros2_edits = [("ros2", "enabled", "true"), ("ros2", "discovery", '"localhost"')]
    (tmp_path / "edits.json").write_text(json.dumps([edits, ros2_edits]))
    editor = tmp_path / "editor.py"
    editor.write_text(EDITOR.format(set_key=inspect.getsource(set_key),
                                    edits=str(tmp_path / "edits.json")))
    # 503 or degraded while a component starts (a scan late on a loaded machine): asked again,
    # up to a minute
    health = (f"{sys.executable} -c 'import sys, urllib.request, urllib.error, time\n"
              f"body = b\"no answer\"\n"
              f"for _ in range(600):\n"
              f"    try:\n"
              f"        body = urllib.request.urlopen(\"http://127.0.0.1:{http_port}/api/health\")"
              f".read()\n"
              f"    except urllib.error.HTTPError as error:\n"
              f"        body = error.read()\n"
              f"    except OSError:\n"
              f"        pass\n"
              f"    if b\"\\\"status\\\": \\\"ok\\\"\" in body: break\n"
              f"    time.sleep(0.1)\n"
              f"sys.stdout.write(body.decode())' >{out}/health.json")
    after = "\n".join([
        f"command -v arbiterd >{out}/which.out",
        f"id -nG arbiterd >{out}/groups.out",
        f"setpriv --reuid=65534 --regid=65534 --clear-groups arbiterd check >{out}/nobody.out 2>&1"
        f" || echo $? >{out}/nobody.rc",
        health,
        f"cp /etc/arbiterd/arbiterd.env /etc/arbiterd/arbiterd.toml {out}/",
        f"readlink /opt/arbiterd/current >{out}/current.out",
    ])
    env = {k: v for k, v in os.environ.items() if not k.startswith("ARBITERD_")}
    env.update(ARBITERD_PIP_ARGS=f"--no-index --find-links {built.wheelhouse}",
               SUDO_EDITOR=f"{sys.executable} {editor}")
    with ArduinoEmulator(devices / "arduino").start() as arduino, \
            RplidarEmulator(devices / "rplidar").start() as lidar:
        device_for(arduino.link)
        device_for(lidar.link)
        try:
            script = step_script(steps, out) + "\nset -e\n" + after
            ran = machine.run(script, env, INSTALL_SH.parent)
        finally:
            if (pid := machine.service_pid()) is not None and Path(f"/proc/{pid}").exists():
                os.kill(pid, signal.SIGKILL)
    report = ran.stdout + ran.stderr + "".join(
        f"\n--- step {i}: {step}\n" + (out / f"step{i}.out").read_text()
        for i, step in enumerate(steps) if (out / f"step{i}.out").exists())
    for i in range(len(steps)):
        assert (out / f"step{i}.rc").read_text().strip() == "0", report
    assert ran.returncode == 0, report
    # the service: the real robot, with the chosen driver, healthy; stopped with safe-stop
    assert "ARBITERD_ARGS=\n" in (out / "arbiterd.env").read_text()
    assert 'type = "serial"' in (out / "arbiterd.toml").read_text()
    body = json.loads((out / "health.json").read_text())
    assert (body["status"], body["mode"], body["driver"]) == ("ok", "hardware", "serial"), \
        json.dumps(body)
    status = (out / "step4.out").read_text()
    assert ": ok (" in status and "hardware mode, driver serial" in status, status
    # the ROS 2 face: a -ros2 release whose venv has the binding; the node runs
    assert (out / "current.out").read_text().strip().endswith("-ros2")
    ros2 = body["components"]["ros2"]
    assert (ros2["status"], ros2["node"], ros2["discovery"]) == ("ok", "/arbiterd", "localhost"), \
        json.dumps(ros2)
    ros2_status = (out / f"step{len(steps) - 1}.out").read_text()
    assert re.search(r"^\s*ros2\s+ok", ros2_status, re.M), ros2_status
    check = (out / "step2.out").read_text()
    assert check.startswith("arbiterd check: ok: /etc/arbiterd/arbiterd.toml"), check
    calls = (machine.state / "systemctl.log").read_text()
    assert "enable --now robot.target" in calls and "ExecStopPost exit 0" in calls, calls
    assert "motors zeroed through the serial driver" in (machine.state / "arbiterd.log").read_text()
    # arbiterd on PATH for every user; the service user in dialout; the udev rules in place
    assert (out / "which.out").read_text().strip() == "/usr/local/bin/arbiterd"
    assert "dialout" in (out / "groups.out").read_text().split()
    installed = (out / "step0.out").read_text()
    assert "service user arbiterd: groups" in installed
    assert "installed, not started. Next:\n    sudoedit /etc/arbiterd/arbiterd.toml" in installed
    for name in ("99-rplidar.rules", "99-arduino.rules"):
        assert (machine.upper(f"/etc/udev/rules.d/{name}")).is_file()
    assert "udevadm control --reload" in (machine.state / "udevadm.log").read_text()
    # a normal user who forgets sudo is told the command to run
    assert (out / "nobody.rc").read_text().strip() == "78"
    assert "run it as root: sudo arbiterd check" in (out / "nobody.out").read_text()


def test_a_failed_daemon_reload_is_redone_by_the_next_run(tmp_path: Path, built: Wheels) -> None:
    root, state = tmp_path / "root", tmp_path / "systemd-state"
    http_port = free_port()
    etc = root / "etc/arbiterd"
    etc.mkdir(parents=True)
    (etc / "arbiterd.toml").write_text(
        f'[driver]\ntype = "mock"\n[http]\nhost = "127.0.0.1"\nport = {http_port}\n'
        f'[rosbridge]\nhost = "127.0.0.1"\nport = {free_port()}\n')
    state.mkdir()
    (state / "fail-daemon-reload").touch()
    env = {"ARBITERD_SYSTEMCTL": str(FAKE_SYSTEMCTL), "FAKE_SYSTEMD_ROOT": str(root),
           "FAKE_SYSTEMD_STATE": str(state)}
    try:
        failed = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel),
                            wheelhouse=built.wheelhouse, env=env)
        assert failed.returncode == 1
        assert ("systemctl daemon-reload failed; fix the cause and re-run this command (it will "
                "reload then)") in failed.stderr
        again = install_sh("systemd", "--root", str(root), "--wheel", str(built.wheel),
                           wheelhouse=built.wheelhouse, env=env)
        assert again.returncode == 0, again.stdout + again.stderr
        assert "finishing what an earlier run left undone" in again.stdout
        recorded = actions(root)
        assert "systemctl daemon-reload" in recorded  # although no unit changed in this run
        assert "systemctl restart arbiterd.service" in recorded
        assert "health: ok" in again.stdout
        assert not (root / "opt/arbiterd/.pending").exists()
    finally:
        install_sh("uninstall", "--root", str(root), env=env)  # stops the fake's daemon


def test_apt_packages_only_raspberry_pi_os_has_are_explained() -> None:
    if Path("/etc/apt/sources.list.d/raspi.list").exists():
        pytest.skip("this machine is Raspberry Pi OS: pigpiod and python3-lgpio are in its apt")
    for driver, package, library in [("pigpio", "pigpiod", "pigpiod, the GPIO daemon"),
                                     ("l298n", "python3-lgpio", "lgpio, the GPIO library")]:
        result = install_sh("systemd", "--dry-run", "--hardware", "--driver", driver)
        assert result.returncode == 1, result.stdout
        message = " ".join(result.stderr.split())
        assert f"install.sh: error: apt has no package {package} on " in message
        assert library in message
        assert "packaged by Raspberry Pi OS in its own apt repository, not by Debian" in message
        assert "What to do instead: install Raspberry Pi OS Bookworm" in message
        assert "github.com/joan2937/" in message and "re-run this command" in message
        assert "--driver serial (an Arduino with ROSArduinoBridge) or --driver odrive_can" \
            in message
        assert "apt-get install" not in result.stdout


def test_sim_installs_only_what_running_needs_and_test_adds_the_test_tools(
        tmp_path: Path) -> None:
    tools = tmp_path / "bin"  # a machine with python3 but none of the test tools
    tools.mkdir()
    for name in ("bash", "cat", "cut", "sha256sum", "dirname", "sed", "env", "apt-get"):
        found = shutil.which(name)
        assert found, name
        (tools / name).symlink_to(found)
    (tools / "python3").symlink_to("/usr/bin/python3" if Path("/usr/bin/python3").exists()
                                   else sys.executable)
    env = {"PATH": str(tools), "ARBITERD_DRY_RUN": "1",
           "ARBITERD_DEV_VENV": str(tmp_path / "venv")}
    sim = install_sh("sim", env=env)
    assert sim.returncode == 0, sim.stderr
    assert "the arbiterd service runs" not in sim.stderr
    assert "system packages: all present" in sim.stdout and "apt-get" not in sim.stdout
    assert f"pip install -q --disable-pip-version-check -e {REPO_DIR}\n" in sim.stdout
    assert "npm" not in sim.stdout
    # the clone's packages compiled, so the daemon does not compile them at every start
    assert (f"[dry-run] {tmp_path}/venv/bin/python -m compileall -q base daemon drivers nav "
            "sensors sim slam\n") in sim.stdout
    test = install_sh("test", env=env)
    assert test.returncode == 0, test.stderr
    apt = next(line for line in test.stdout.splitlines() if " apt-get install " in line)
    assert {"nodejs", "npm", "openssh-client", "rsync", "systemd"} <= set(apt.split())
    extras = dev_extras().replace(",", "\\,")  # printf %q
    assert f"-e {REPO_DIR}\\[{extras}\\]\n" in test.stdout
    venv_bin = f"[dry-run] {tmp_path}/venv/bin/"
    runs = [line for line in test.stdout.splitlines() if line.startswith(venv_bin)]
    assert runs[-3:] == [venv_bin + "ruff check .", venv_bin + "mypy",  # the gates, then
                         venv_bin + "python -m pytest"], test.stdout   # the tests
    # on a robot whose service is running, sim says the ports are taken and what to do
    (tools / "systemctl").write_text("#!/bin/sh\n[ \"$1\" = is-active ] && exit 0; exit 1\n")
    (tools / "systemctl").chmod(0o755)
    on_robot = install_sh("sim", env=env)
    assert ("the arbiterd service runs on this machine and holds its HTTP and rosbridge ports; "
            "stop it first (sudo systemctl stop robot.target) or give this one other ports: "
            "./install.sh sim --http-port PORT --ws-port PORT") in on_robot.stderr


def dev_extras() -> str:
    """The extras ./install.sh dev installs by default (its DEV_EXTRAS)."""
    extras = re.search(r'DEV_EXTRAS="\$\{ARBITERD_DEV_EXTRAS:-([^}]*)\}"',
                       INSTALL_SH.read_text())
    assert extras, "install.sh's DEV_EXTRAS"
    return extras[1]


@pytest.mark.parametrize("failing", ["ruff", "mypy", None])
def test_the_test_command_stops_at_a_failing_gate_before_pytest(
        tmp_path: Path, failing: str | None) -> None:
    """`./install.sh test` (what .ci/run runs) runs ruff, then mypy, then pytest, and stops with
    the gate's name at the first one that fails. Here on a copy of install.sh whose venv is up
    to date and holds stand-ins that log their calls."""
    src, tools, venv_bin = tmp_path / "src", tmp_path / "bin", tmp_path / "venv" / "bin"
    for path in (src, tools, venv_bin):
        path.mkdir(parents=True)
    shutil.copy(INSTALL_SH, src)
    shutil.copy(REPO_DIR / "pyproject.toml", src)
    calls = tmp_path / "calls.log"
    for name in ("ruff", "mypy", "python"):
        fails = "echo 'deliberate finding' >&2; exit 1" if name == failing else "exit 0"
        (venv_bin / name).write_text(f'#!/bin/sh\necho {name} "$@" >>{calls}\n{fails}\n')
    for name in ("node", "npm", "sshd", "ssh", "ssh-keygen", "rsync", "systemd-analyze",
                 "chromium"):  # the test tools, present
        (tools / name).write_text("#!/bin/sh\nexit 0\n")
    for path in [*venv_bin.iterdir(), *tools.iterdir()]:
        path.chmod(0o755)
    for name in ("bash", "cat", "cut", "sha256sum", "dirname", "sed"):
        found = shutil.which(name)
        assert found, name
        (tools / name).symlink_to(found)
    python = "/usr/bin/python3" if Path("/usr/bin/python3").exists() else sys.executable
    (tools / "python3").symlink_to(python)
    version = subprocess.run([python, "-V"], capture_output=True, text=True, check=True)
    pyproject_hash = hashlib.sha256((src / "pyproject.toml").read_bytes()).hexdigest()
    (venv_bin.parent / ".arbiterd-dev-stamp").write_text(
        f"{pyproject_hash} {version.stdout.strip()}\n{dev_extras()}\n")
    result = subprocess.run(
        ["bash", str(src / "install.sh"), "test", "-q", "tests/x.py"], capture_output=True,
        text=True, timeout=60, check=False, cwd=tmp_path,
        env={"PATH": str(tools), "ARBITERD_DEV_VENV": str(venv_bin.parent),
             "ARBITERD_CHROMIUM": str(tools / "chromium")})
    every_step = ["ruff check .", "mypy", "python -m pytest -q tests/x.py"]
    compiled, *ran = calls.read_text().splitlines()  # the set-up compiles the sources first
    assert compiled == "python -m compileall -q base daemon drivers nav sensors sim slam"
    if failing is None:
        assert result.returncode == 0, result.stderr
        assert ran == every_step
        return
    assert result.returncode == 1, result.stdout + result.stderr
    assert ran == every_step[:["ruff", "mypy"].index(failing) + 1]  # nothing after the failure
    assert "deliberate finding" in result.stderr
    assert f"install.sh: error: gate {failing} failed" in result.stderr
    assert "the tests did not run" in result.stderr
    assert "running the test suite" not in result.stdout


def test_arduino_rule_names_the_usual_boards_for_dialout_only() -> None:
    boards = set()
    for line in (SYSTEMD_DIR / "99-arduino.rules").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        fields = dict(part.strip().replace("+=", "=").replace("==", "=").split("=", 1)
                      for part in line.split(","))
        assert fields["SUBSYSTEM"] == '"tty"' and fields["SYMLINK"] == '"arduino"', line
        assert fields["GROUP"] == '"dialout"' and fields["MODE"] == '"0660"', line
        boards.add((fields["ATTRS{idVendor}"].strip('"'),
                    fields.get("ATTRS{idProduct}", "*").strip('"')))
    assert boards == {("2341", "*"), ("1a86", "7523"), ("0403", "6001")}


# -- the README's Quick start with Debian 12's own Python (what a Pi has) -----------------------

SYSTEM_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"


def fresh_clone(dest: Path) -> Path:
    """The checkout's files as a clone has them (tracked and new, nothing ignored)."""
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others",
                             "--exclude-standard"], cwd=REPO_DIR, capture_output=True,
                            check=True, timeout=60).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = REPO_DIR / name
        if source.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)
    return dest


@pytest.mark.timeout(1800)
def test_readme_quick_start_with_debian_python(tmp_path: Path) -> None:
    """Both Quick start commands on a clone whose python3 is Debian's (3.11.2, pip 23.0.1, no
    `wheel` in its venvs), with an empty pip cache so every sdist is really built. Without the
    ROS 2 extras (a 250 MB download and a Cyclone DDS build each time): the CI run, which is
    `./install.sh test` itself, installs those."""
    if not Path("/usr/bin/python3").exists():
        pytest.skip("no /usr/bin/python3 (Debian's own Python) on this machine")
    clone = fresh_clone(tmp_path / "clone")
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("ARBITERD_", "PYENV", "VIRTUAL_ENV", "PIP_CACHE"))}
    env.update(PATH=SYSTEM_PATH, PIP_CACHE_DIR=str(tmp_path / "pip-cache"),
               ARBITERD_DEV_EXTRAS="test,dev,bench")
    assert Path(shutil.which("python3", path=SYSTEM_PATH) or "").resolve() == \
        Path("/usr/bin/python3").resolve()
    # ./install.sh test: the part that failed was building the test wheels (sdnotify's sdist)
    tested = subprocess.run(
        ["./install.sh", "test", "-q", "-p", "no:cacheprovider", f"--basetemp={tmp_path}/t",
         "-n", "0", "--timeout=600", "tests/test_install.py", "-k", "release_venv_runs"],
        cwd=clone, env=env, capture_output=True, text=True, timeout=1500, check=False)
    assert tested.returncode == 0, tested.stdout[-6000:] + tested.stderr[-6000:]
    assert "1 passed" in tested.stdout, tested.stdout[-3000:]
    venv_cfg = (clone / ".venv/pyvenv.cfg").read_text()
    assert "home = /usr/bin\n" in venv_cfg, venv_cfg
    # ./install.sh sim: the daemon on the simulated robot, until Ctrl-C
    port = free_port()
    env.update(ARBITERD_HTTP_HOST="127.0.0.1", ARBITERD_HTTP_PORT=str(port),
               ARBITERD_ROSBRIDGE_HOST="127.0.0.1", ARBITERD_ROSBRIDGE_PORT=str(free_port()))
    log = tmp_path / "sim.log"
    with log.open("w") as out:
        sim = subprocess.Popen(["./install.sh", "sim"], cwd=clone, env=env, stdout=out,
                               stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        body = wait_for(lambda: sim_health(port, sim, log), "/api/health of ./install.sh sim",
                        within_s=300)
        assert body["mode"] == "sim" and body["status"] in ("ok", "degraded"), body
    finally:
        sim.send_signal(signal.SIGINT)
        assert sim.wait(30) == 0, log.read_text()
    assert "virtual environment" in log.read_text() and "up to date" in log.read_text()


def sim_health(port: int, sim: subprocess.Popen[bytes], log: Path) -> dict[str, object] | None:
    assert sim.poll() is None, log.read_text()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=1) as reply:
            body: dict[str, object] = json.load(reply)
    except urllib.error.HTTPError as exc:
        body = json.load(exc)
    except OSError:
        return None
    return body


def test_the_service_users_groups_are_verified(tmp_path: Path) -> None:
    """On a machine without a 'gpio' group (not Raspberry Pi OS) the l298n driver cannot reach
    /dev/gpiochip*: the install stops at the user step and says why and what to do."""
    if why := machine_available():
        pytest.skip(f"runs useradd in a private mount namespace: {why}")
    if grp_exists("gpio"):
        pytest.skip("this machine has a gpio group (Raspberry Pi OS): nothing to refuse")
    machine = Machine(tmp_path / "machine")
    # lgpio "built from source": a module the system Python finds, so the packages step passes
    script = ("mkdir -p /usr/local/lib/python3/dist-packages\n"
              "echo '# stand-in' >/usr/local/lib/python3/dist-packages/lgpio.py\n"
              "export PYTHONPATH=/usr/local/lib/python3/dist-packages\n"
              "./install.sh systemd --hardware --driver l298n --no-start")
    env = {k: v for k, v in os.environ.items() if not k.startswith("ARBITERD_")}
    ran = machine.run(script, env, REPO_DIR, timeout_s=120)
    assert ran.returncode == 1, ran.stdout + ran.stderr
    message = " ".join(ran.stderr.split())
    assert "group gpio does not exist here (not a Raspberry Pi OS image?)" in message
    assert ("install.sh: error: the service user arbiterd is not in group(s) gpio, so it cannot "
            "open the robot's devices.") in message
    assert "Create the missing group(s) and a udev rule giving them the devices" in message
    assert "installing release" not in ran.stdout  # stopped before anything was built


def grp_exists(name: str) -> bool:
    try:
        grp.getgrnam(name)
    except KeyError:
        return False
    return True


def test_dev_setup_installs_the_compiler_and_headers_a_minimal_debian_lacks(
        tmp_path: Path) -> None:
    """Issue 40 item 0: the ros2 extra's binding compiles, so a machine with only python3 gets
    gcc and python3-dev from the dev and test setup, not only from `systemd --ros2`."""
    headless = tmp_path / "python3"  # a Python whose headers are not installed
    headless.write_text(f'#!/bin/sh\ncase "$*" in *sysconfig*) echo /nonexistent; exit 0;; esac\n'
                        f'exec {sys.executable} "$@"\n')
    headless.chmod(0o755)
    fresh = str(tmp_path / "venv")  # no venv yet: the binding is to be built
    result = install_sh("dev", "--dry-run", env={"ARBITERD_PYTHON": str(headless),
                                                 "ARBITERD_CC": "no-such-compiler",
                                                 "ARBITERD_DEV_VENV": fresh})
    assert result.returncode == 0, result.stderr
    apt = next(line for line in result.stdout.splitlines() if "apt-get install" in line)
    assert " gcc" in apt and " python3-dev" in apt, apt
    result = install_sh("dev", "--dry-run", env={"ARBITERD_PYTHON": sys.executable,
                                                 "ARBITERD_DEV_VENV": fresh})
    assert "python3-dev" not in result.stdout and " gcc" not in result.stdout, result.stdout


@pytest.mark.parametrize(("args", "port"), [((), "8085"), (("--http-port", "18085"), "18085"),
                                            (("--http-port=18086",), "18086")])
def test_sim_names_the_address_it_will_really_serve(args: tuple[str, ...], port: str) -> None:
    """Issue 40 item 6: `install.sh sim --http-port P` said to open :8085."""
    result = install_sh("sim", *args, env={"ARBITERD_DRY_RUN": "1"})
    assert result.returncode == 0, result.stderr
    assert f"open http://localhost:{port}/" in result.stdout + result.stderr
