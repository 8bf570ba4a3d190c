"""The deployment's images, built from the project's own inputs (`ares deploy images`).

Two bases, one Dockerfile (deploy/Dockerfile, BASE_IMAGE): the official Python image where a
registry is reachable (`--base python`), or a Debian bookworm made here by debootstrap from
Debian's packages and turned into an image by `docker import` (`--base debootstrap`: a depot
that reaches no registry). Inside the build, apt, pip and npm reach their package indexes; the
host's CA bundle goes in as a build secret (`ca`), for networks that re-sign TLS, never as a
layer. Each step's time comes from BuildKit's own progress (`#N DONE 12.3s`), each image's size
from the engine.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ares.deploy.engine import SETUP_HINT, Engine, EngineError, connect_or_start

REPO = Path(__file__).resolve().parents[2]
ARES_IMAGE = "ares:0.1.0"  # as deploy/*/compose.yaml name it
DEBOOTSTRAP_IMAGE = "ares-base:bookworm"
PYTHON_IMAGE = "python:3.11.7-slim-bookworm"  # the Dockerfile's default BASE_IMAGE
SUITE = "bookworm"
CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")

Progress = Callable[[str], None]


@dataclass
class Step:
    name: str
    seconds: float
    cached: bool = False


@dataclass
class BuiltImage:
    tag: str
    seconds: float
    size_mb: float
    steps: list[Step] = field(default_factory=list)


@dataclass
class ImagesResult:
    base: str
    images: list[BuiltImage]
    engine_started: bool
    ok: bool
    error: str = ""
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


DEFAULT_MIRROR = "http://deb.debian.org/debian"


def mirror_of(sources: str) -> str | None:
    """The first Debian archive (not its security archive) of an apt sources text, deb822 or one-line."""
    match = re.search(r"(?:^URIs:[ \t]*|^deb[ \t]+(?:\[[^\]]*\][ \t]+)?)(https?://\S+/debian)/?(?=\s)", sources, re.M)
    return match.group(1) if match else None


def debian_mirror() -> str:
    """The Debian mirror this host's apt uses, else deb.debian.org."""
    for path in (Path("/etc/apt/sources.list.d/debian.sources"), Path("/etc/apt/sources.list")):
        try:
            found = mirror_of(path.read_text())
        except OSError:
            continue
        if found:
            return found
    return DEFAULT_MIRROR


def image_size_mb(engine: Engine, tag: str) -> float:
    size = engine.docker("image", "inspect", "--format", "{{.Size}}", tag).stdout.strip()
    return round(int(size) / 1e6, 1)


def debootstrap_base(engine: Engine, progress: Progress, tag: str = DEBOOTSTRAP_IMAGE) -> BuiltImage:
    """Debian's minimal base from Debian's packages, imported as an image (apt caches left out)."""
    debootstrap = shutil.which("debootstrap")
    if debootstrap is None:
        raise EngineError(f"no debootstrap: {SETUP_HINT}")
    began = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ares-rootfs-") as tmp:
        rootfs = Path(tmp) / "rootfs"
        mirror = debian_mirror()
        progress(f"debootstrap --variant=minbase {SUITE} from {mirror}")
        done = subprocess.run(
            [debootstrap, "--variant=minbase", SUITE, str(rootfs), mirror],
            capture_output=True,
            text=True,
            timeout=1800,
        )
        if done.returncode != 0:
            raise EngineError(f"debootstrap failed: {(done.stderr or done.stdout).strip()[-800:]}")
        strapped = time.monotonic() - began
        for junk in ("var/cache/apt/archives", "var/lib/apt/lists"):
            for item in (rootfs / junk).glob("*"):
                if item.is_file():
                    item.unlink()
        archive = Path(tmp) / "rootfs.tar"
        with tarfile.open(archive, "w") as tar:
            tar.add(rootfs, arcname=".")
        progress(f"docker import -> {tag}")
        imported_at = time.monotonic()
        engine.docker("import", "--change", 'CMD ["/bin/bash"]', str(archive), tag, timeout_s=600)
        imported = time.monotonic() - imported_at
    return BuiltImage(
        tag=tag,
        seconds=round(time.monotonic() - began, 1),
        size_mb=image_size_mb(engine, tag),
        steps=[Step("debootstrap", round(strapped, 1)), Step("docker import", round(imported, 1))],
    )


_STEP_NAME = re.compile(r"^#(\d+) (\[.+)$")
_STEP_DONE = re.compile(r"^#(\d+) DONE (\d+(?:\.\d+)?)s$")
_STEP_CACHED = re.compile(r"^#(\d+) CACHED$")


def steps_of(lines: Iterable[str], progress: Progress | None = None) -> list[Step]:
    """Each BuildKit step (`--progress plain`) with its time: `#N [stage k/n] WHAT` names step N
    (said again when steps interleave), `#N DONE 12.3s` ends it, `#N CACHED` took none."""
    names: dict[str, str] = {}
    steps: list[Step] = []
    for line in lines:
        line = line.rstrip()
        if match := _STEP_NAME.match(line):
            if match.group(1) not in names and progress and re.search(r"\] (RUN|COPY|FROM) ", match.group(2)):
                progress(match.group(2)[:110])
            names.setdefault(match.group(1), match.group(2))
        elif (match := _STEP_DONE.match(line)) and match.group(1) in names:
            steps.append(Step(names[match.group(1)][:160], float(match.group(2))))
        elif (match := _STEP_CACHED.match(line)) and match.group(1) in names:
            steps.append(Step(names[match.group(1)][:160], 0.0, cached=True))
    return steps


def build_ares(engine: Engine, base_image: str, progress: Progress, tag: str = ARES_IMAGE) -> BuiltImage:
    """deploy/Dockerfile on `base_image`, each step timed as BuildKit reports it."""
    args = ["build", "-f", str(REPO / "deploy" / "Dockerfile"), "--build-arg", f"BASE_IMAGE={base_image}"]
    if CA_BUNDLE.exists():
        args += ["--secret", f"id=ca,src={CA_BUNDLE}"]
    args += ["--progress", "plain", "-t", tag, str(REPO)]
    began = time.monotonic()
    tail: list[str] = []
    proc = subprocess.Popen(
        [engine.client, *args],
        env=engine.env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert proc.stdout is not None

    def kept(lines: Iterable[str]) -> Iterator[str]:
        nonlocal tail
        for line in lines:
            tail = (tail + [line.rstrip()])[-40:]
            yield line

    steps = steps_of(kept(proc.stdout), progress)
    if proc.wait() != 0:
        raise EngineError("docker build failed:\n" + "\n".join(tail[-25:]))
    return BuiltImage(
        tag=tag, seconds=round(time.monotonic() - began, 1), size_mb=image_size_mb(engine, tag), steps=steps
    )


def build_images(base: str, progress: Progress, engine: Engine | None = None) -> ImagesResult:
    """Both images for `base` ('debootstrap' or 'python'); the engine started here is stopped after."""
    began = time.monotonic()
    own = engine is None
    images: list[BuiltImage] = []
    try:
        engine = engine or connect_or_start()
    except EngineError as exc:
        return ImagesResult(base=base, images=[], engine_started=False, ok=False, error=str(exc))
    try:
        progress(f"engine at {engine.host}{' (started here)' if engine.started else ''}")
        if base == "debootstrap":
            images.append(debootstrap_base(engine, progress))
            base_image = DEBOOTSTRAP_IMAGE
        elif base == "python":
            progress(f"base {PYTHON_IMAGE} from its registry")
            engine.docker("pull", PYTHON_IMAGE, timeout_s=900)
            images.append(BuiltImage(PYTHON_IMAGE, 0.0, image_size_mb(engine, PYTHON_IMAGE)))
            base_image = PYTHON_IMAGE
        else:
            raise EngineError(f"unknown base {base!r}: debootstrap or python")
        images.append(build_ares(engine, base_image, progress))
        return ImagesResult(
            base=base,
            images=images,
            engine_started=engine.started,
            ok=True,
            seconds=round(time.monotonic() - began, 1),
        )
    except (EngineError, subprocess.TimeoutExpired, OSError) as exc:
        return ImagesResult(
            base=base,
            images=images,
            engine_started=engine.started,
            ok=False,
            error=str(exc),
            seconds=round(time.monotonic() - began, 1),
        )
    finally:
        if own:
            engine.stop()


def have_image(engine: Engine, tag: str) -> bool:
    return engine.docker("image", "inspect", tag, check=False).returncode == 0
