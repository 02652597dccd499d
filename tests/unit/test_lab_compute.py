"""`nod lab secure` issues the lab's Dask cluster its identities: a CA of its own, the
scheduler's, workers' and clients' certificates and keys, a Dask config per role, and prints the
commands that start the cluster with them."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.exceptions import InvalidSignature

from services.lab.secure import main as secure_main


def _verifies(ca: Path, cert: Path) -> bool:
    issuer, leaf = (x509.load_pem_x509_certificate(p.read_bytes()) for p in (ca, cert))
    try:
        leaf.verify_directly_issued_by(issuer)
    except (InvalidSignature, ValueError):  # a signature of another key, or another issuer
        return False
    return True


def test_secure_writes_the_dask_identities_and_says_how_to_start_the_cluster(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "tls"
    assert secure_main(["--out", str(out), "--router-host", "control.lab",
                        "--dask-host", "compute.lab", "--days", "30"]) == 0
    printed = capsys.readouterr().out
    d = out / "dask"
    for role in ("scheduler", "worker", "client"):
        folder = d / role
        assert {p.name for p in folder.iterdir()} == {"ca.pem", "cert.pem", "key.pem", "dask.yaml"}
        assert stat.S_IMODE((folder / "key.pem").stat().st_mode) == 0o600
        assert (folder / "ca.pem").read_bytes() == (d / "ca.pem").read_bytes()
        cert = x509.load_pem_x509_certificate((folder / "cert.pem").read_bytes())
        assert cert.subject.rfc4514_string().startswith(f"CN=dask.{role}")
        assert "compute CA" in cert.issuer.rfc4514_string()
        assert _verifies(d / "ca.pem", folder / "cert.pem")
        # The cluster's CA is its own: no Zenoh identity passes it, no Dask one the router's.
        assert not _verifies(out / "ca.pem", folder / "cert.pem")
        assert not _verifies(d / "ca.pem", out / "monitor" / "cert.pem")
        # Dask reads its config file as YAML: the role's files and encryption required.
        import yaml

        conf = yaml.safe_load((folder / "dask.yaml").read_text())["distributed"]["comm"]
        assert conf["require-encryption"] is True and conf["default-scheme"] == "tls"
        assert conf["tls"]["ca-file"] == str((folder / "ca.pem").absolute())
        assert conf["tls"][role] == {"cert": str((folder / "cert.pem").absolute()),
                                     "key": str((folder / "key.pem").absolute())}
    assert stat.S_IMODE((d / "ca.key").stat().st_mode) == 0o600
    absd = d.absolute()
    assert (f"dask scheduler --host tls://compute.lab --port 8786 --tls-ca-file {absd}/scheduler/"
            f"ca.pem --tls-cert {absd}/scheduler/cert.pem --tls-key {absd}/scheduler/key.pem"
            ) in printed
    assert f"dask worker tls://compute.lab:8786 --tls-ca-file {absd}/worker/ca.pem" in printed
    assert f"--scheduler tls://compute.lab:8786 --tls-dir {absd}/client" in printed
    assert "--dashboard-address 127.0.0.1:8787" in printed  # the scheduler's HTTP: loopback


def test_the_dask_identities_come_with_every_layout_and_no_rig_may_take_their_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "lab"
    assert secure_main(["--out", str(out), "--rigs", "rig1,rig2", "--router-host", "router.lab",
                        "--days", "30"]) == 0
    assert (out / "dask" / "client" / "cert.pem").is_file()
    assert "dask scheduler --host tls://router.lab" in capsys.readouterr().out  # the default
    per_rig = tmp_path / "per-rig"
    assert secure_main(["--out", str(per_rig), "--rigs", "rig1,rig2", "--router-per-rig",
                        "--router-host", "router.lab", "--rig-router", "rig1=r1.lab:7447",
                        "--rig-router", "rig2=r2.lab:7447", "--days", "30"]) == 0
    assert (per_rig / "dask" / "worker" / "dask.yaml").is_file()
    assert f"--tls-dir {per_rig.absolute()}/dask/client" in capsys.readouterr().out
    assert secure_main(["--out", str(tmp_path / "x"), "--rigs", "rig1,dask"]) == 2
    err = capsys.readouterr().err
    assert "may not be called" in err and "'dask'" in err and len(err.splitlines()) == 1
