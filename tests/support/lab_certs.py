"""Test certificates of a lab CA, made at test time with the ``openssl`` command (never
committed): :func:`make_ca`, :func:`make_cert` (EC P-256, v3, SANs), and
:func:`lab_configs` (the shipped tpods/net_configs examples with their paths and router
address filled in)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[2] / "tpods" / "net_configs"


def openssl_refusal() -> str | None:
    return None if shutil.which("openssl") else "the `openssl` command is not installed"


def _run(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True, timeout=30)


def make_ca(folder: Path, name: str = "ca") -> tuple[Path, Path]:
    """A self-signed CA in ``folder``: (certificate, key)."""
    folder.mkdir(parents=True, exist_ok=True)
    key, pem = folder / f"{name}.key", folder / f"{name}.pem"
    _run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-keyout", str(key), "-out", str(pem), "-days", "2", "-subj", f"/CN=tpods lab {name}",
         "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign")
    return pem, key


def make_cert(folder: Path, name: str, ca: tuple[Path, Path],
              sans: tuple[str, ...] = ("DNS:localhost", "IP:127.0.0.1")) -> tuple[Path, Path]:
    """A certificate of common name ``name`` signed by ``ca``: (certificate, key)."""
    key, csr, pem = folder / f"{name}.key", folder / f"{name}.csr", folder / f"{name}.pem"
    ext = folder / f"{name}.ext"
    ext.write_text("basicConstraints=CA:FALSE\nkeyUsage=digitalSignature\n"
                   "extendedKeyUsage=serverAuth,clientAuth\n"
                   f"subjectAltName={','.join(sans)}\n")
    _run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-keyout", str(key), "-out", str(csr), "-subj", f"/CN={name}")
    _run("x509", "-req", "-in", str(csr), "-CA", str(ca[0]), "-CAkey", str(ca[1]),
         "-CAcreateserial", "-out", str(pem), "-days", "2", "-extfile", str(ext))
    return pem, key


def lab_configs(folder: Path, router_ep: str, names: tuple[str, ...]) -> dict[str, Path]:
    """The shipped router and client examples for this test: the certificate folder for
    /etc/tpods/, the router's listen endpoint and each client's own certificate; a dict
    ``{"router": path, name: path, ...}``."""
    d = str(folder) + "/"
    router = (CONFIGS / "router.json5").read_text().replace("/etc/tpods/", d)
    router = router.replace('"tls/0.0.0.0:7447"', f'"{router_ep}"')
    out = {"router": folder / "router.json5"}
    out["router"].write_text(router)
    client = (CONFIGS / "client.json5").read_text().replace("/etc/tpods/", d)
    client = client.replace('"tls/router.lab:7447"', f'"{router_ep}"')
    for n in names:
        p = folder / f"{n}.json5"
        p.write_text(client.replace("client.pem", f"{n}.pem").replace("client.key", f"{n}.key"))
        out[n] = p
    return out
