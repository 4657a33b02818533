# A real OpenSSH server on a loopback port, for the deploy-pi.sh tests; started and stopped by them.
from __future__ import annotations

import getpass
import os
import socket
import subprocess
from dataclasses import dataclass
from pathlib import Path

from tests.support.net import free_port
from tests.support.wait import wait_for

SSHD = Path("/usr/sbin/sshd")
START_TIMEOUT_S = 20.0


@dataclass
class SshServer:
    port: int
    user: str
    identity: Path
    client_options: str  # for ARBITERD_SSH_OPTS
    process: subprocess.Popen[bytes]
    log: Path

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)


def keygen(path: Path) -> None:
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(path)], check=True,
                   timeout=30)


def wait_listening(port: int, process: subprocess.Popen[bytes], log: Path) -> None:
    def listening() -> bool:
        if process.poll() is not None:
            raise RuntimeError(f"sshd exited with {process.returncode}: {log.read_text()}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return True
        except OSError:
            return False

    wait_for(listening, lambda: f"sshd to listen on {port}: {log.read_text()}",
             within_s=START_TIMEOUT_S, interval_s=0.05)


def start_sshd(work: Path, session_env: dict[str, str]) -> SshServer:
    """sshd on 127.0.0.1, key login for the current user, SetEnv for every session."""
    assert SSHD.exists(), "openssh-server missing: ./install.sh dev installs it"
    work.mkdir(parents=True, exist_ok=True)
    keygen(work / "host_key")
    keygen(work / "client_key")
    (work / "authorized_keys").write_text((work / "client_key.pub").read_text())
    if os.geteuid() == 0:  # sshd as root insists on its privilege-separation directory
        Path("/run/sshd").mkdir(mode=0o755, exist_ok=True)
    port = free_port()
    set_env = " ".join(f"{k}={v}" for k, v in session_env.items())
    config = work / "sshd_config"
    config.write_text(
        f"Port {port}\nListenAddress 127.0.0.1\nHostKey {work}/host_key\n"
        f"PidFile {work}/sshd.pid\nAuthorizedKeysFile {work}/authorized_keys\n"
        "PasswordAuthentication no\nKbdInteractiveAuthentication no\nPubkeyAuthentication yes\n"
        "PermitRootLogin prohibit-password\nStrictModes no\nUsePAM no\n"
        f"SetEnv {set_env}\n")
    log = work / "sshd.log"
    with log.open("wb") as out:
        process = subprocess.Popen([str(SSHD), "-D", "-e", "-f", str(config)], stdout=out,
                                   stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    wait_listening(port, process, log)
    options = (f"-F /dev/null -o UserKnownHostsFile={work}/known_hosts "
               "-o StrictHostKeyChecking=accept-new")
    return SshServer(port=port, user=getpass.getuser(), identity=work / "client_key",
                     client_options=options, process=process, log=log)
