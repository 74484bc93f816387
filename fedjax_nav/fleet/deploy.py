"""The Deployment Engine on one machine (docs/fleet.md): a Flower SuperLink and one SuperNode per
robot as separate processes on 127.0.0.1, TLS and SuperNode authentication on, and `flwr run` of
the project's Flower app (`fleet.apps`: `server` and `app`) writing a normal run directory.

    python -m fedjax_nav.fleet.deploy thesis/flddpg run.episodes=10 fed.period=2 --out runs/fleet

Everything the deployment makes is kept beside the run directory, in OUT.deploy/: the TLS
certificates (a CA and the SuperLink's certificate for 127.0.0.1), each robot's SSH key pair
(its public key registered with the SuperLink before it connects), the Flower app
(app/pyproject.toml), the Flower CLI's connection (home/config.toml) and every process's log.
The same files and commands put one SuperNode on each robot of a real fleet (docs/fleet.md).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from fedjax_nav import rundir
from fedjax_nav.config import Config, load_config, save_config
from fedjax_nav.fleet.robot import FleetError, check, rounds

BIN = Path(sys.executable).parent  # flower-superlink, flower-supernode, flwr: the same environment's
# The project's Flower app: what `flwr run` bundles and the SuperLink runs (fleet.apps).
APP_TOML = """\
[build-system]
requires = ["hatchling"]
build-backend = "hatchling.build"

[project]
name = "fedjax-nav-fleet"
version = "1.0.0"
description = "fedjax_nav's federated round on Flower (docs/fleet.md)"
license = "MIT"
dependencies = ["fedjax_nav[fleet]"]

[tool.hatch.build.targets.wheel]
packages = ["."]

[tool.flwr.app]
publisher = "fedjax-nav"

[tool.flwr.app.components]
serverapp = "fedjax_nav.fleet.apps:server"
clientapp = "fedjax_nav.fleet.apps:app"

[tool.flwr.app.config]
config = ""              # the run's config file (a fedjax_nav config, every override resolved)
out = ""                 # the run directory the server writes (resumed if it holds this run's fleet state)
round-timeout = 600.0    # seconds a round waits for the robots' replies (then goes on without the others)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_tls(folder: Path) -> dict[str, Path]:
    """A CA and the SuperLink's certificate for 127.0.0.1 / localhost signed by it (PEM files)."""
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    days = datetime.timedelta(days=365)

    def cert(subject, issuer, key, sign_key, ca, sans=()):
        b = x509.CertificateBuilder().subject_name(subject).issuer_name(issuer).public_key(key.public_key())
        b = b.serial_number(x509.random_serial_number()).not_valid_before(now - days).not_valid_after(now + days)
        b = b.add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        if sans:
            b = b.add_extension(x509.SubjectAlternativeName(list(sans)), critical=False)
        return b.sign(sign_key, hashes.SHA256())

    name = lambda cn: x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
    ca_key, key = ec.generate_private_key(ec.SECP384R1()), ec.generate_private_key(ec.SECP384R1())
    ca = cert(name("fedjax_nav fleet CA"), name("fedjax_nav fleet CA"), ca_key, ca_key, True)
    sans = (x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1")))
    server = cert(name("localhost"), ca.subject, key, ca_key, False, sans)
    paths = {"ca": folder / "ca.crt", "cert": folder / "server.pem", "key": folder / "server.key"}
    paths["ca"].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths["cert"].write_bytes(server.public_bytes(serialization.Encoding.PEM))
    paths["key"].write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    return paths


def make_node_key(folder: Path, name: str) -> tuple[Path, Path]:
    """A SuperNode's EC (P-384) key pair in OpenSSH format: (private, public)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    folder.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP384R1())
    private, public = folder / name, folder / f"{name}.pub"
    private.write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.OpenSSH, serialization.NoEncryption())
    )
    private.chmod(0o600)
    public.write_bytes(
        key.public_key().public_bytes(serialization.Encoding.OpenSSH, serialization.PublicFormat.OpenSSH)
    )
    return private, public


@dataclass
class Deployment:
    """The processes of one deployment on 127.0.0.1 and the files they share (`work`)."""

    work: Path
    tls: bool = True
    auth: bool = True
    port: int = field(default_factory=free_port)
    procs: list[subprocess.Popen] = field(default_factory=list)
    pids: dict[str, int] = field(default_factory=dict)
    ports: list[int] = field(default_factory=list)  # the SuperLink's and every SuperNode's (ports.json)

    def __post_init__(self):
        self.work.mkdir(parents=True, exist_ok=True)
        self._listen(self.port)
        self.certs = make_tls(self.work / "certs") if self.tls else None
        home = self.work / "home"
        home.mkdir(exist_ok=True)
        security = f'root-certificates = "{self.certs["ca"]}"' if self.tls else "insecure = true"
        (home / "config.toml").write_text(
            f'[superlink]\ndefault = "fleet"\n\n[superlink.fleet]\naddress = "127.0.0.1:{self.port}"\n{security}\n'
        )
        (self.work / "app").mkdir(exist_ok=True)
        (self.work / "app" / "pyproject.toml").write_text(APP_TOML)
        # Each round of a robot runs in a new `flwr-clientapp` process (the SuperNode's subprocess
        # isolation): JAX's persistent compilation cache spares it the compile of the rounds after
        # the first. A user's own JAX_COMPILATION_CACHE_DIR is kept.
        cache = {"JAX_COMPILATION_CACHE_DIR": os.environ.get("JAX_COMPILATION_CACHE_DIR", str(self.work / "jax-cache"))}
        self.env = os.environ | {"FLWR_HOME": str(home)} | cache

    def _listen(self, port: int) -> int:
        """`port`, noted in ports.json (every port of every deployment in this folder, a resumed
        one's too: what a leftover process would still talk to)."""
        self.ports.append(port)
        f = self.work / "ports.json"
        rundir.write_json(f, sorted(set(json.loads(f.read_text()) if f.exists() else []) | set(self.ports)))
        return port

    def _start(self, name: str, args: list[str]) -> subprocess.Popen:
        log = open(self.work / f"{name}.log", "a")
        proc = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env=self.env, cwd=self.work, start_new_session=True
        )
        self.procs.append(proc)
        self.pids[name] = proc.pid  # each process leads its own group (os.killpg stops it and its children)
        rundir.write_json(self.work / "pids.json", self.pids)
        return proc

    def start_superlink(self, timeout: float = 60.0) -> subprocess.Popen:
        args = [str(BIN / "flower-superlink"), "--port", str(self.port), "--disable-runtime-dependency-installation"]
        if self.tls:
            c = self.certs
            args += ["--ssl-ca-certfile", str(c["ca"]), "--ssl-certfile", str(c["cert"])]
            args += ["--ssl-keyfile", str(c["key"])]
        else:
            args.append("--insecure")
        if self.auth:
            args.append("--enable-supernode-auth")
        proc = self._start("superlink", args)
        start = time.monotonic()
        while socket.socket().connect_ex(("127.0.0.1", self.port)) != 0:
            if proc.poll() is not None or time.monotonic() - start > timeout:
                raise FleetError(f"superlink: did not start (see {self.work / 'superlink.log'})")
            time.sleep(0.3)
        return proc

    def flwr(self, *args: str, timeout: float | None = 120.0) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(BIN / "flwr"), *args], env=self.env, cwd=self.work, capture_output=True, text=True, timeout=timeout
        )

    def register(self, public_key: Path) -> int:
        """Register a SuperNode's public key with the SuperLink; its node id."""
        out = self.flwr("supernode", "register", str(public_key), "fleet", "--format", "json")
        try:
            return int(json.loads(out.stdout)["node-id"])
        except (ValueError, KeyError) as err:
            why = f"{out.stdout.strip()} {out.stderr.strip()}"
            raise FleetError(f"flwr supernode register {public_key}: {why}") from err

    def start_supernode(self, index: int, key: Path | None, retries: int | None = None) -> subprocess.Popen:
        """SuperNode `index` (node config partition-id=index) of robot `index`, signing with `key`."""
        args = [str(BIN / "flower-supernode"), "--superlink", f"127.0.0.1:{self.port}"]
        state = self.work / "robots"  # the robot's own disk: its state after each round
        args += ["--port", str(self._listen(free_port())), "--node-config", f"partition-id={index} state-dir='{state}'"]
        args += ["--root-certificates", str(self.certs["ca"])] if self.tls else ["--insecure"]
        if key is not None:
            args += ["--auth-supernode-private-key", str(key)]
        if retries is not None:
            args += ["--max-retries", str(retries)]
        return self._start(f"supernode-{index}", args)

    def restart_supernode(self, index: int, key: Path | None, timeout: float = 300.0) -> subprocess.Popen:
        """Start robot `index`'s SuperNode again, as a supervisor would (systemd's Restart=on-failure):
        the SuperLink refuses a key whose last connection it still counts online (until two
        heartbeats of 30 s are missed), so a start that exits at once is tried again."""
        start = time.monotonic()
        while True:
            proc = self.start_supernode(index, key)
            try:
                proc.wait(timeout=8.0)
            except subprocess.TimeoutExpired:
                return proc  # connected (or retrying its connection): running
            if time.monotonic() - start > timeout:
                raise FleetError(f"supernode-{index}: not accepted again in {timeout:.0f} s ({self.work}/*.log)")
            time.sleep(4.0)

    def run(self, config: Path, out: Path, timeout: float, round_timeout: float = 600.0) -> subprocess.CompletedProcess:
        """`flwr run` of the app on this SuperLink; returns when the run has ended."""
        run_config = f"config='{config.resolve()}' out='{out.resolve()}' round-timeout={float(round_timeout)}"
        app = str(self.work / "app")
        result = self.flwr("run", app, "fleet", "--run-config", run_config, "--stream", timeout=timeout)
        (self.work / "run.log").write_text(result.stdout + result.stderr)
        return result

    def stop(self) -> None:
        for proc in reversed(self.procs):
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        for proc in self.procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                pass
            try:  # and whatever of its group outlived it (a ServerApp or ClientApp subprocess)
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for pid in strays(self.ports):  # app processes in their own session, orphaned by a killed parent
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def strays(ports) -> list[int]:
    """Live Flower app processes (flwr-serverapp, flwr-clientapp) talking to 127.0.0.1 on one of
    `ports`: a SuperLink or SuperNode starts them in their own session, so a SIGKILL of its group
    leaves them running (found after a killed SuperLink). Linux's /proc; none elsewhere."""
    found, proc_dir = [], Path("/proc")
    for proc in proc_dir.iterdir() if proc_dir.is_dir() else ():
        try:
            words = (proc / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if proc.name.isdigit() and any("flwr-" in w for w in words[:2]):
            if any(w == f"127.0.0.1:{p}" for w in words for p in ports):
                found.append(int(proc.name))
    return found


def deploy(
    cfg: Config,
    out: str | Path,
    *,
    tls: bool = True,
    auth: bool = True,
    timeout: float = 3600.0,
    round_timeout: float = 600.0,
    resume: bool = False,
) -> dict:
    """Run `cfg` on the Deployment Engine on this machine (one SuperNode process per robot) and
    return its summary (summary.json of the run directory `out`). `resume`: go on with the run in
    `out` (its server's round state and the robots' saved states) after a stop or a kill."""
    check(cfg)
    out = Path(out)
    held = rundir.results_in(out)
    if resume and not (out / rundir.FLEET_STATE).exists():
        raise FleetError(f"{out}: holds no fleet run to resume ({rundir.FLEET_STATE})")
    if held and not resume:  # results are never overwritten
        raise FleetError(f"{out}: holds a run already ({', '.join(held)}); choose another --out, or --resume it")
    work = out.with_name(out.name + ".deploy")
    work.mkdir(parents=True, exist_ok=True)
    save_config(cfg, work / "run.yaml")
    d = Deployment(work, tls=tls, auth=auth)
    try:
        d.start_superlink()
        for i in range(cfg.num_robots):
            private = work / "keys" / f"robot-{i}"
            if not private.exists():
                make_node_key(work / "keys", f"robot-{i}")
            if auth:
                d.register(private.with_suffix(".pub"))
            d.start_supernode(i, private)
        result = d.run(work / "run.yaml", out, timeout, round_timeout)
    finally:
        d.stop()
    return finished(out, work, rounds(cfg), result)


def finished(out: Path, work: Path, total: int, result: subprocess.CompletedProcess) -> dict:
    """The summary of a run that did all its rounds; a one-line FleetError otherwise."""
    tail = " | ".join((result.stdout + result.stderr).strip().splitlines()[-2:])
    if not (out / rundir.SUMMARY).exists():
        raise FleetError(f"{out}: the deployment wrote no run directory ({work}/*.log): {tail}")
    summary = rundir.read_json(out / rundir.SUMMARY)
    if summary.get("rounds_done", 0) < total:
        done = summary.get("rounds_done", 0)
        raise FleetError(f"{out}: the run stopped after round {done} of {total} ({work}/*.log); go on with --resume")
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fedjax_nav.fleet.deploy", description=__doc__.split("\n\n")[0])
    ap.add_argument("config", help="a shipped config name (thesis/flddpg) or a config file")
    ap.add_argument("overrides", nargs="*", help="dotted overrides, e.g. run.episodes=10")
    ap.add_argument("--out", required=True, help="the run directory (OUT.deploy/: the deployment's files)")
    ap.add_argument("--insecure", action="store_true", help="no TLS and no SuperNode authentication")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds the run may take")
    ap.add_argument("--round-timeout", type=float, default=600.0, help="seconds a round waits for replies")
    ap.add_argument("--resume", action="store_true", help="go on with the run in --out after a stop or a kill")
    a = ap.parse_args(argv)
    try:
        cfg = load_config(a.config, a.overrides)
        secure = not a.insecure
        summary = deploy(
            cfg, a.out, tls=secure, auth=secure, timeout=a.timeout, round_timeout=a.round_timeout, resume=a.resume
        )
    except (FleetError, FileExistsError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(
        json.dumps({k: summary[k] for k in ("method", "episodes_done", "rounds_done", "reward_last") if k in summary})
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
