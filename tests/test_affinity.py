"""CPU affinity: the `cpus:` section, `--vehicle-cpus`, and a process pinned as a whole (every thread,
and the threads it starts later). The supervisor's children on their CPUs: tests/test_supervisor.py."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from ares import cli
from ares.app import run_config
from ares.app.supervisor import check_cpus
from ares.cli.args import cpu_list
from ares.cli.run import run_options
from ares.core import affinity, config
from tests.helpers.stack import REPO


@pytest.mark.parametrize("text, cpus", [("0", [0]), ("1,0", [0, 1]), ("0-3", [0, 1, 2, 3]), ("2, 0-1", [0, 1, 2])])
def test_cpu_lists_read_as_taskset_writes_them(text, cpus):
    assert cpu_list(text) == cpus


@pytest.mark.parametrize("text", ["", "a", "3-1", "-1", "0,,1", "1-x"])
def test_a_bad_cpu_list_is_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match="not a CPU list"):
        cpu_list(text)


@pytest.mark.parametrize(
    "section, complaint",
    [
        ({"vehicle": []}, "cpus.vehicle: give CPU numbers"),
        ({"simulator": [-1]}, "cpus.simulator: give CPU numbers"),
        ({"vehicel": [0]}, "vehicel"),
    ],
)
def test_a_bad_cpus_section_names_its_key(section, complaint):
    with pytest.raises(config.ConfigError, match=complaint):
        run_config.build((), {"cpus": section})


def test_cpus_default_to_any():
    assert run_config.build()["cpus"] == {"vehicle": None, "simulator": None, "host": None}


def test_cpus_this_machine_lacks_are_a_clear_error():
    missing = max(affinity.available()) + 1
    cpus = config.CpuSettings(vehicle=[missing])
    with pytest.raises(config.ConfigError, match=f"cpus.vehicle: CPU {missing} is not available here"):
        check_cpus(cpus)
    check_cpus(config.CpuSettings(vehicle=sorted(affinity.available())))


def test_run_refuses_vehicle_cpus_the_machine_lacks(capsys):
    missing = max(affinity.available()) + 1
    assert cli.main(["run", "--headless", "--vehicle-cpus", str(missing)]) == 2
    assert f"CPU {missing} is not available here" in capsys.readouterr().err


def test_vehicle_cpus_give_the_simulator_and_the_host_the_others():
    first, *others = sorted(affinity.available())
    args = cli.build_parser().parse_args(["run", "--vehicle-cpus", str(first)])
    over = run_options(args).overrides()
    rest = others or None  # a machine of one CPU: everything shares it
    assert over["cpus"] == {"vehicle": [first], "simulator": rest, "host": rest}


PIN_SCRIPT = """
import os, sys, threading, time
from ares.core import affinity
started = threading.Event()
threading.Thread(target=lambda: (started.set(), time.sleep(5)), daemon=True).start()
started.wait()
affinity.pin_process([int(sys.argv[1])])
late = threading.Event()
threading.Thread(target=lambda: (late.set(), time.sleep(5)), daemon=True).start()
late.wait()
print(sorted({tuple(sorted(os.sched_getaffinity(int(t)))) for t in os.listdir("/proc/self/task")}))
"""


def test_a_pinned_process_runs_every_thread_on_its_cpus():
    cpu = max(affinity.available())
    result = subprocess.run(
        [sys.executable, "-c", PIN_SCRIPT, str(cpu)], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    # the main thread, the thread started before and the one started after: all on `cpu` alone
    assert result.stdout.strip() == f"[({cpu},)]"
