"""A throwaway PostgreSQL cluster for the test session: Debian's ``postgresql`` binaries, a data
directory under /tmp, 127.0.0.1 on a free port, removed afterwards.

``initdb`` refuses to run as root, so when the tests run as root the cluster is created and run
as the ``postgres`` user the Debian package creates (its directory is handed to that user).
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

USER = "magline"


def bindir() -> Path:
    found = shutil.which("pg_ctl")
    if found:
        return Path(os.path.realpath(found)).parent
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"))
    if not candidates:
        raise RuntimeError("PostgreSQL is not installed: the README's test command installs Debian's postgresql")
    return Path(candidates[-1]).parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _as_cluster_owner(argv: list[str]) -> list[str]:
    return ["runuser", "-u", "postgres", "--", *argv] if os.geteuid() == 0 else argv


class Cluster:
    def __init__(self, base: Path, port: int) -> None:
        self.base, self.port = base, port

    def url(self, database: str) -> str:
        return f"postgresql+psycopg://{USER}:not-a-secret@127.0.0.1:{self.port}/{database}"

    def new_database(self) -> str:
        """A fresh, empty database; its SQLAlchemy URL."""
        import psycopg

        name = f"t_{uuid.uuid4().hex[:12]}"
        with psycopg.connect(host="127.0.0.1", port=self.port, user=USER, dbname="postgres", autocommit=True) as db:
            db.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def stop(self) -> None:
        subprocess.run(_as_cluster_owner([str(bindir() / "pg_ctl"), "-D", str(self.base / "data"), "-m", "fast",
                                          "-w", "stop"]), capture_output=True, timeout=60)

    def running(self) -> bool:
        return subprocess.run(_as_cluster_owner([str(bindir() / "pg_ctl"), "-D", str(self.base / "data"), "status"]),
                              capture_output=True, timeout=30).returncode == 0

    def start_if_stopped(self) -> None:
        if not self.running():
            self.start()

    def start(self) -> None:
        subprocess.run(_as_cluster_owner([
            str(bindir() / "pg_ctl"), "-D", str(self.base / "data"), "-l", str(self.base / "server.log"), "-w",
            "-o", f"-p {self.port} -k {self.base} -c listen_addresses=127.0.0.1 -c fsync=off",
            "start"]), check=True, capture_output=True, timeout=60)


@contextlib.contextmanager
def cluster() -> Iterator[Cluster]:
    base = Path(tempfile.mkdtemp(prefix="magline-pg-"))
    try:
        if os.geteuid() == 0:
            shutil.chown(base, "postgres", "postgres")
        subprocess.run(_as_cluster_owner([str(bindir() / "initdb"), "-D", str(base / "data"), "-U", USER,
                                          "--auth=trust", "-E", "UTF8", "--no-sync"]),
                       check=True, capture_output=True, timeout=120)
        server = Cluster(base, _free_port())
        server.start()
        try:
            yield server
        finally:
            server.stop()
    finally:
        shutil.rmtree(base, ignore_errors=True)
