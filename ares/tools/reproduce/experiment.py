"""What one reproduced experiment is: the paper's figure and numbers, ARES's beside them, and the
picture that shows them.

An experiment is a function of a `Context` (where to write its picture, whether to run the short
version, how to say progress) that returns an `ExperimentResult`: a table of `Row`s, each the
paper's value beside ARES's, and a note where ARES differs from the paper by design."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Row:
    figure: str
    paper: float | str | None  # None: the paper gives no number for it
    ares: float | str | None
    unit: str = ""
    note: str = ""  # why they differ, when they do by design


@dataclass
class ExperimentResult:
    id: str
    title: str
    paper_ref: str  # the paper and its figure or equation
    rows: list[Row]
    picture: Path | None = None
    notes: list[str] = field(default_factory=list)  # what ARES does differently, said beside the numbers
    seconds: float = 0.0  # wall time it took

    def as_json(self) -> dict:
        out = asdict(self)
        out["picture"] = None if self.picture is None else str(self.picture)
        return out


@dataclass(frozen=True)
class Drive:
    """A headless drive an experiment asks for: `ares run --headless --speed max` with these."""

    seconds: float
    scenario: str | None = None
    controller: str | None = None  # pinned (None: the control manager chooses)
    start_s_m: float | None = None


@dataclass(frozen=True)
class Driven:
    figures: dict  # the headless run's result, as `ares run --headless` prints it
    store: Path  # its black box (the embedded store's file)


@dataclass(frozen=True)
class Context:
    out: Path  # the report's folder: pictures go here
    drive: Callable[[Drive, Path], Driven]  # runs a drive in a folder of its own (ares/tools/reproduce/drives.py)
    quick: bool = False  # the short version (tests): fewer seconds of driving, fewer points
    progress: Callable[[str], None] = lambda _message: None


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    paper_ref: str
    run: Callable[[Context], ExperimentResult]

    def __call__(self, ctx: Context) -> ExperimentResult:
        started = time.monotonic()
        ctx.progress(f"{self.id}: {self.title}")
        result = self.run(ctx)
        result.seconds = round(time.monotonic() - started, 1)
        return result
