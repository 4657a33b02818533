# [ros2] security: the enclave's files checked at start, each bad one named (exit 78).
from __future__ import annotations

import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon.components.ros2 import security
from daemon.components.ros2.dds import available
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.sros2 import make_keystore, openssl_missing

YEAR_2100 = 4102444800.0


@pytest.fixture(scope="module")
def keystore(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    if openssl_missing():
        pytest.skip(openssl_missing())
    yield make_keystore(tmp_path_factory.mktemp("sros2") / "keystore", "arbiterd")


def copy(enclaves: Path, tmp_path: Path) -> Path:
    target = tmp_path / "arbiterd"
    shutil.copytree(enclaves / "arbiterd", target)
    return target


def test_the_documented_recipe_makes_a_valid_enclave(keystore: Path) -> None:
    found = security.enclave(str(keystore / "arbiterd"))
    xml = security.cyclone_xml(found, None)
    assert f"file:{keystore / 'arbiterd' / 'permissions.p7s'}" in xml
    assert "init_authentication" in xml and "init_access_control" in xml


@pytest.mark.parametrize("name", [*security.CERTIFICATES, security.KEY, *security.SIGNED])
def test_a_missing_file_is_named(keystore: Path, tmp_path: Path, name: str) -> None:
    enclave = copy(keystore, tmp_path)
    (enclave / name).unlink()
    with pytest.raises(security.SecurityError, match=re.escape(f"{enclave / name}: missing")):
        security.enclave(str(enclave))


@pytest.mark.parametrize(("name", "why"), [("cert.pem", "not a PEM certificate"),
                                           ("key.pem", "not a PEM private key"),
                                           ("governance.p7s", "not a signed"),
                                           ("identity_ca.cert.pem", "empty")])
def test_a_file_of_the_wrong_kind_is_named(keystore: Path, tmp_path: Path, name: str,
                                           why: str) -> None:
    enclave = copy(keystore, tmp_path)
    (enclave / name).write_text("" if why == "empty" else "hello\n")
    with pytest.raises(security.SecurityError, match=re.escape(f"{enclave / name}: {why}")):
        security.enclave(str(enclave))


def test_an_expired_certificate_is_named(keystore: Path) -> None:
    with pytest.raises(security.SecurityError, match=re.escape("cert.pem: expired on")):
        security.enclave(str(keystore / "arbiterd"), now=YEAR_2100)


def test_not_a_directory(tmp_path: Path) -> None:
    with pytest.raises(security.SecurityError, match="not a directory"):
        security.enclave(str(tmp_path / "nowhere"))


def test_the_daemon_refuses_to_start_naming_the_file(keystore: Path, tmp_path: Path) -> None:
    if available() is not None:
        pytest.skip(str(available()))
    enclave = copy(keystore, tmp_path)
    (enclave / "permissions.p7s").unlink()
    toml = (f'[ros2]\nenabled = true\ndiscovery = "localhost"\nsecurity = "{enclave}"\n')
    daemon = DaemonSubprocess(tmp_path, toml, args=("--sim",)).start(wait_ready=False)
    try:
        assert daemon.proc is not None and daemon.proc.wait(60) == 78
        assert f"[ros2] security: {enclave / 'permissions.p7s'}: missing" in daemon.log()
    finally:
        daemon.__exit__(None, None, None)
