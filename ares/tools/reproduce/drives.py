"""The drives the experiments ask for, as `ares run --headless --speed max` runs them: the whole
stack under its supervisor, each in a folder of its own with its own black box."""

from __future__ import annotations

from pathlib import Path

from ares.tools.reproduce.experiment import Drive, Driven


class DriveFailed(RuntimeError):
    pass


def stack_drive(drive: Drive, folder: Path) -> Driven:
    from ares.app import stack
    from ares.app.run_options import RunOptions

    folder.mkdir(parents=True, exist_ok=True)
    store = folder / "blackbox.sqlite"
    settings = {} if drive.start_s_m is None else {"sim": {"start_s_m": drive.start_s_m}}
    result = stack.run(
        RunOptions(
            headless=True,
            speed="max",
            seconds=drive.seconds,
            scenario=drive.scenario,
            controller=drive.controller,
            run_dir=folder / "run",
            store=str(store),
            settings=settings,
        )
    )
    if result.refused or result.interrupted:
        raise DriveFailed(f"the drive in {folder} did not run: {result.error}")
    return Driven(result.summary(), store)
