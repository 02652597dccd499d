"""The lab's Dask cluster, locked like its Zenoh network: mutual TLS with certificates of a CA.

A Dask scheduler runs whatever its clients send, on every worker, as the workers' user; so a
lab's cluster (`nod cohort --scheduler`, `nod calibrate-cohort`, `nod fit`, `nod analyze power`)
admits only who shows a certificate it trusts, and speaks only TLS. `nod lab secure` writes:

    out/dask/ca.pem, out/dask/ca.key      the compute CA (keep ca.key offline, like out/ca.key)
    out/dask/scheduler/                   copy to the scheduler's machine
    out/dask/worker/                      copy to every worker machine
    out/dask/client/                      copy to the machines that run `nod cohort …`
                                          (`--tls-dir`, or $NOD_DASK_TLS)

each role folder holding `cert.pem`, `key.pem` (readable by its owner only), `ca.pem` and
`dask.yaml` (Dask's config for that role: the CA, the role's certificate and key, encryption
required, tls:// by default; `DASK_CONFIG=…/dask.yaml` instead of the `--tls-*` flags).

The cluster's CA is its own, not the lab's Zenoh CA: Dask checks that a peer's certificate is
signed by its CA and nothing else (no name, no role), so with one CA for both, every Zenoh
identity — the read-only monitor of a lab screen too — could run code on the workers, and every
Dask certificate would pass the router's TLS (its ACL, deny by default, would stop it there, but
the workers have no ACL). Two CAs keep each network's keys to itself.
"""

from __future__ import annotations

import json
from pathlib import Path

from services.lab.certs import write_ca, write_cert

DASK = "dask"  # the folder under --out
ROLES = ("scheduler", "worker", "client")
PORT = 8786  # Dask's scheduler port
WHERE = {
    "scheduler": "the scheduler's machine",
    "worker": "every worker machine",
    "client": "the machines that run `nod cohort … --scheduler` (--tls-dir)",
}


def dask_config(folder: Path, role: str) -> dict:
    """Dask's configuration of `role` with the identity in `folder` (as the hosts will see it)."""
    return {
        "distributed": {
            "comm": {
                "require-encryption": True,
                "default-scheme": "tls",
                "tls": {
                    "ca-file": str(folder / "ca.pem"),
                    role: {"cert": str(folder / "cert.pem"), "key": str(folder / "key.pem")},
                },
            }
        }
    }


def write_dask(out: Path, install_dir: Path, days: int) -> list[Path]:
    """The compute CA and the scheduler's, workers' and clients' identities; return the files."""
    root = out / DASK
    root.mkdir(parents=True, exist_ok=True)
    ca_key, ca, written = write_ca(root, days, "nod-hri lab compute CA")
    for role in ROLES:
        folder = root / role
        written += write_cert(folder, f"{DASK}.{role}", None, ca_key, ca, days)
        config = dask_config(install_dir / DASK / role, role)
        head = f"# Dask's {role}: mutual TLS. Written by `nod lab secure`; regenerate, not edit.\n"
        # JSON is YAML: no YAML writer needed, and Dask reads it as the YAML it is.
        (folder / "dask.yaml").write_text(head + json.dumps(config, indent=2) + "\n")
        written.append(folder / "dask.yaml")
    return written


def commands(install_dir: Path, host: str, port: int = PORT) -> list[str]:
    """The lines `nod lab secure` prints: how to start the cluster and reach it."""
    d = install_dir / DASK

    def tls(role: str) -> str:
        f = d / role
        return f"--tls-ca-file {f}/ca.pem --tls-cert {f}/cert.pem --tls-key {f}/key.pem"

    address = f"tls://{host}:{port}"
    return [
        f"  the Dask cluster (cohorts, fits): copy {d}/scheduler/ to {WHERE['scheduler']}, "
        f"worker/ to {WHERE['worker']}, client/ to {WHERE['client']}",
        f"    scheduler: dask scheduler --host tls://{host} --port {port} {tls('scheduler')} "
        "--no-dashboard --dashboard-address 127.0.0.1:8787",
        f"    each worker (an unprivileged user): dask worker {address} {tls('worker')} "
        "--nworkers CORES --nthreads 1 --no-dashboard --dashboard-address 127.0.0.1:0",
        f"    (or, for each: DASK_CONFIG={d}/<role>/dask.yaml and the same command without "
        "--tls-*)",
        f"    nod cohort … --scheduler {address} --tls-dir {d}/client (or NOD_DASK_TLS="
        f"{d}/client)",
        f"  keep {d}/ca.key offline too: whoever holds it can run code on the workers",
    ]
