# DDS Security on the face: a reader with an enclave of the same keystore reads, one without none.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.paths import REPO
from tests.support.sros2 import make_keystore, openssl_missing

TOKEN = "ros2-security-test-token"
DOMAIN = 45
READER = REPO / "tests" / "ros2_netns" / "dds_reader.py"
WINDOW_S = 8.0


def reader(enclave: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, str(READER), str(DOMAIN), enclave, str(WINDOW_S)],
                            cwd=REPO, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def received(process: subprocess.Popen[str]) -> int:
    out, err = process.communicate(timeout=WINDOW_S + 60)
    assert process.returncode == 0, out + err
    return int(out.strip().splitlines()[-1].split()[-1])


def test_a_secure_reader_receives_the_scan_and_an_unauthenticated_one_nothing(
        tmp_path: Path) -> None:
    if openssl_missing():
        pytest.skip(openssl_missing())
    enclaves = make_keystore(tmp_path / "keystore", "arbiterd", "viewer")
    toml = (f'[security]\ntoken = "{TOKEN}"\n'
            f'[ros2]\nenabled = true\ndomain_id = {DOMAIN}\ndiscovery = "localhost"\n'
            f'security = "{enclaves / "arbiterd"}"\n')
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        _, health = daemon.get("/api/health", token=TOKEN)
        assert health["components"]["ros2"]["security"] == str(enclaves / "arbiterd")
        secure, open_reader = reader(str(enclaves / "viewer")), reader("-")
        assert received(secure) > 0
        assert received(open_reader) == 0


def test_the_same_reader_without_an_enclave_reads_an_open_face(tmp_path: Path) -> None:
    """The control for the 0 above: without [ros2] security the unauthenticated reader reads."""
    toml = (f'[security]\ntoken = "{TOKEN}"\n'
            f'[ros2]\nenabled = true\ndomain_id = {DOMAIN}\ndiscovery = "localhost"\n')
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)):
        assert received(reader("-")) > 0
