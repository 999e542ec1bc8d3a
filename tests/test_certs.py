"""A run's TLS identities (``rgtbus certs``, rgtbus.bus.certs): what is made, and every bad file
refused in one line naming it, before anything runs."""

from __future__ import annotations

import datetime
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from rgtbus.bus.certs import ROUTER, WATCH, check_tls, make_certs, paths, process_tls
from rgtbus.cli import main
from rgtbus.errors import RgtbusError

ROOT = Path(__file__).parent.parent
GATE = str(ROOT / "scenarios" / "gate.toml")
UNITS = ["a", "b", "c", "d"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """The gate's identities, made once (tests copy it before they spoil anything)."""
    d = tmp_path_factory.mktemp("certs") / "gate"
    make_certs(UNITS, d, label="gate")
    return d


@pytest.fixture
def spoilt(run_dir, tmp_path) -> Path:
    """A copy of the run's directory, to spoil."""
    d = tmp_path / "spoilt"
    shutil.copytree(run_dir, d)
    return d


def load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def common_name(cert: x509.Certificate) -> str:
    return str(cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value)


def test_certs_are_a_ca_and_one_pair_an_identity_each_named_and_signed_by_it(run_dir):
    assert sorted(p.name for p in run_dir.iterdir()) == sorted(
        [f"{u}.{x}" for u in UNITS for x in ("crt", "key")] + ["run"]
    )
    assert sorted(p.name for p in (run_dir / "run").iterdir()) == [
        "ca.crt", "ca.key", "router.crt", "router.key", "watch.crt", "watch.key",
    ]  # fmt: skip
    ca = load(run_dir / "run" / "ca.crt")
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    assert ca.extensions.get_extension_for_class(x509.KeyUsage).value.key_cert_sign
    for identity in [*UNITS, ROUTER, WATCH]:
        crt, key = paths(run_dir, identity)
        cert = load(crt)
        assert common_name(cert) == identity
        cert.verify_directly_issued_by(ca)  # raises unless the run's CA signed it
        assert not cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
        usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        assert set(usage) == {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH}
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert names.get_values_for_type(x509.DNSName)  # a DNS-safe name, and loopback
        assert [str(ip) for ip in names.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
        assert isinstance(cert.public_key(), ec.EllipticCurvePublicKey)
        assert cert.public_key().curve.name == "secp256r1"
        days = (cert.not_valid_after_utc - cert.not_valid_before_utc).total_seconds() / 86400
        assert 30 <= days < 30.01  # the default, from a few minutes ago
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
        assert stat.S_IMODE(crt.stat().st_mode) == 0o644
        assert check_tls(run_dir, identity).cert == crt
    assert stat.S_IMODE((run_dir / "run" / "ca.key").stat().st_mode) == 0o600
    assert common_name(load(paths(run_dir, ROUTER)[0])) == "@router"


def test_certs_refuse_to_overwrite_unless_forced(tmp_path):
    d = tmp_path / "ids"
    make_certs(["a", "b"], d)
    before = (d / "run" / "ca.crt").read_bytes()
    with pytest.raises(RgtbusError, match=r"ca\.crt: exists \(give --force"):
        make_certs(["a", "b"], d)
    assert (d / "run" / "ca.crt").read_bytes() == before
    (d / "b.key").chmod(0o644)
    make_certs(["a", "b"], d, force=True)
    assert (d / "run" / "ca.crt").read_bytes() != before  # a new CA, and every pair under it
    assert stat.S_IMODE((d / "b.key").stat().st_mode) == 0o600
    for u in ("a", "b"):
        check_tls(d, u)


def test_certs_refuse_bad_names_and_days(tmp_path):
    for units, days, needle in [
        (["a", "@router"], 30, "bad unit name '@router'"),
        (["a", "a"], 30, "a unit named twice"),
        ([], 30, "no unit"),
        (["a"], 0, "--days 0"),
        (["a"], float("nan"), "--days nan"),
    ]:
        with pytest.raises(RgtbusError, match=needle):
            make_certs(units, tmp_path / "x", days=days)
    assert not (tmp_path / "x").exists()


def _sign(path: Path, run_dir: Path, cn: str, start: datetime.datetime, days: float) -> None:
    """Write at ``path`` a certificate for ``cn`` signed by the run's own CA key, valid from
    ``start`` for ``days``, with the key of ``path``'s pair (so only its dates are wrong)."""
    ca = load(run_dir / "run" / "ca.crt")
    ca_key = serialization.load_pem_private_key((run_dir / "run" / "ca.key").read_bytes(), None)
    key = serialization.load_pem_private_key(path.with_suffix(".key").read_bytes(), None)
    assert isinstance(ca_key, ec.EllipticCurvePrivateKey)
    assert isinstance(key, ec.EllipticCurvePrivateKey)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + datetime.timedelta(days=days))
        .sign(ca_key, hashes.SHA256())
    )
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _cases(d: Path, other: Path) -> list[tuple[str, str]]:
    """Spoil ``d`` one way after another (``other``: another run's directory); each: the unit
    to check and the line expected."""
    now = datetime.datetime.now(datetime.UTC)
    return [
        ("missing dir", f"{d}/nowhere: no such directory of TLS identities"),
        ("missing ca", f"{d}/run/ca.crt: missing (the run's CA certificate)"),
        ("missing crt", f"{d}/b.crt: missing (the certificate of unit 'b')"),
        ("missing key", f"{d}/b.key: missing (the key of {d}/b.crt)"),
        ("malformed ca", f"{d}/run/ca.crt: not a PEM certificate (malformed)"),
        ("malformed crt", f"{d}/b.crt: not a PEM certificate (malformed)"),
        ("malformed key", f"{d}/b.key: not a PEM private key (malformed)"),
        ("foreign", f"{d}/b.crt: not signed by the run's CA {d}/run/ca.crt (a foreign"),
        ("expired", f"{d}/b.crt: expired on {(now - datetime.timedelta(days=1)):%Y-%m-%d}"),
        ("not yet", f"{d}/b.crt: not valid before {(now + datetime.timedelta(days=1)):%Y-%m-%d}"),
        ("c's pair", f"{d}/b.crt is the certificate of 'c', not of unit 'b'"),
        ("c's key", f"{d}/b.key is not the key of {d}/b.crt"),
        ("router's pair", f"{d}/b.crt is the certificate of '@router', not of unit 'b'"),
        ("a unit as router", f"{d}/run/router.crt is the certificate of 'b', not of the router"),
    ]


def _spoil(case: str, d: Path, other: Path) -> tuple[Path, str]:
    """Spoil ``d`` as ``case`` says; the directory and identity to check."""
    now = datetime.datetime.now(datetime.UTC)
    b_crt, b_key = d / "b.crt", d / "b.key"
    if case == "missing dir":
        return d / "nowhere", "b"
    if case == "missing ca":
        (d / "run" / "ca.crt").unlink()
    elif case == "missing crt":
        b_crt.unlink()
    elif case == "missing key":
        b_key.unlink()
    elif case == "malformed ca":
        (d / "run" / "ca.crt").write_text("-----BEGIN CERTIFICATE-----\nnot base64\n")
    elif case == "malformed crt":
        b_crt.write_bytes(b_crt.read_bytes()[:200])
    elif case == "malformed key":
        b_key.write_text("hello")
    elif case == "foreign":
        shutil.copy(other / "b.crt", b_crt)
        shutil.copy(other / "b.key", b_key)
    elif case == "expired":
        _sign(b_crt, d, "b", now - datetime.timedelta(days=31), 30)
    elif case == "not yet":
        _sign(b_crt, d, "b", now + datetime.timedelta(days=1), 30)
    elif case == "c's pair":
        shutil.copy(d / "c.crt", b_crt)
        shutil.copy(d / "c.key", b_key)
    elif case == "c's key":
        shutil.copy(d / "c.key", b_key)
    elif case == "router's pair":
        shutil.copy(d / "run" / "router.crt", b_crt)
        shutil.copy(d / "run" / "router.key", b_key)
    elif case == "a unit as router":
        shutil.copy(b_crt, d / "run" / "router.crt")
        shutil.copy(b_key, d / "run" / "router.key")
        return d, ROUTER
    return d, "b"


CASES = [c for c, _ in _cases(Path("/x"), Path("/y"))]


@pytest.fixture(scope="module")
def other_run(tmp_path_factory) -> Path:
    """Another run's identities: its CA is not ours."""
    d = tmp_path_factory.mktemp("other") / "other"
    make_certs(UNITS, d)
    return d


@pytest.mark.parametrize("case", CASES)
def test_every_bad_file_is_one_line_naming_it(spoilt, other_run, case):
    expected = dict(_cases(spoilt, other_run))[case]
    where, identity = _spoil(case, spoilt, other_run)
    with pytest.raises(RgtbusError) as err:
        check_tls(where, identity)
    assert str(err.value).startswith(expected), str(err.value)
    assert "\n" not in str(err.value)


def test_one_certificate_a_process(run_dir):
    assert process_tls(run_dir, ["b"]).identity == "b"
    with pytest.raises(RgtbusError, match=r"2 units in one process \(a, b\): a process proves"):
        process_tls(run_dir, ["a", "b"])


def test_the_cli_makes_certs_and_refuses_to_overwrite_them(tmp_path, capsys):
    out = tmp_path / "ids"
    assert main(["certs", GATE, "--out", str(out), "--days", "2"]) == 0
    said = capsys.readouterr().out
    assert f"{out}/run/ca.key: keep it off the hosts" in said and f"{out}/d.key" in said
    cert = load(out / "a.crt")
    assert (cert.not_valid_after_utc - cert.not_valid_before_utc).days == 2
    assert main(["certs", GATE, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"rgtbus certs: error: {out}/run/ca.crt: exists (give --force to replace the run's "
        "certificates)\n"
    )
    assert main(["certs", GATE, "--out", str(out), "--force", "--quiet"]) == 0
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("case", ["c's pair", "c's key", "foreign", "expired", "missing ca"])
def test_unit_launch_router_and_watch_refuse_a_bad_file_before_they_start(
    spoilt, other_run, tmp_path, capsys, case
):
    """Exit 2 and the one line, before any log is written or endpoint opened."""
    expected = dict(_cases(spoilt, other_run))[case]
    _spoil(case, spoilt, other_run)
    log = tmp_path / "b.mcap"
    commands = [
        ["unit", "b", GATE, "--tls", str(spoilt), "--log", str(log), "-l", "tls/127.0.0.1:1"],
        ["launch", GATE, "--tls", str(spoilt), "--log-dir", str(tmp_path / "launch")],
    ]
    if case in ("foreign", "missing ca"):  # the run-wide files are spoilt for these too
        expected_router = expected.replace("/b.crt", "/run/router.crt")
        commands += [
            ["router", "--tls", str(spoilt), "--scenario", GATE, "-l", "tls/127.0.0.1:1"],
        ]
        if case == "missing ca":
            commands += [
                ["watch", "--tls", str(spoilt), "--scenario", GATE, "--live", "127.0.0.1:0"]
            ]
        if case == "foreign":
            shutil.copy(other_run / "run" / "router.crt", spoilt / "run" / "router.crt")
            shutil.copy(other_run / "run" / "router.key", spoilt / "run" / "router.key")
    for argv in commands:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        want = expected_router if argv[0] == "router" else expected
        assert err.startswith(f"rgtbus {argv[0]}: error: {want}"), (argv, err)
        assert err.count("\n") == 1
    assert not log.exists() and not (tmp_path / "launch").exists()


def test_a_unit_with_another_units_certificate_is_refused_exit_2(spoilt, other_run, tmp_path):
    """``rgtbus unit b --tls DIR`` where DIR's b.crt and b.key are c's: refused, as a process
    of its own, before it runs."""
    _spoil("c's pair", spoilt, other_run)
    proc = subprocess.run(
        [sys.executable, "-m", "rgtbus", "unit", "b", GATE, "--tls", str(spoilt), "--log",
         str(tmp_path / "b.mcap")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr == (
        f"rgtbus unit: error: {spoilt}/b.crt is the certificate of 'c', not of unit 'b'\n"
    )
    assert not (tmp_path / "b.mcap").exists()
