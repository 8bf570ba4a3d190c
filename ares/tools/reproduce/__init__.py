"""`ares reproduce`: the papers' experiments run on ARES, each beside the paper's numbers and
figure, in one Markdown report with its pictures.

| id           | the paper's                        | what runs                                           |
|--------------|------------------------------------|-----------------------------------------------------|
| dbw-steps    | DBW Figs. 25-26, §5.1              | the board's PID on the simulated actuators          |
| dbw-takeover | DBW Fig. 28, §5.2                  | a 100 s drive with the takeover scenario            |
| ares-fig15   | ARES Fig. 15, §3.6.1               | the MPC and Stanley, each pinned on the tour        |
| ares-fig14   | ARES Fig. 14, §3.5.3               | trapezoid and rectangle along the narrow lane       |

Each experiment is a function of a Context (ares/tools/reproduce/experiment.py); the drives it
asks for run as `ares run --headless --speed max` (drives.py), or, in tests, on the in-process
stack. Not yet here: the campus test (DBW Fig. 27), eqs. 15-20 and 21-25, ARES Figs. 4, 9, 17-20.
"""

from __future__ import annotations

from ares.tools.reproduce import dbw_steps, lateral, obstacle_zone, takeover
from ares.tools.reproduce.experiment import Experiment

EXPERIMENTS = {
    e.id: e
    for e in (
        Experiment("dbw-steps", "Drive-by-wire step responses", "DBW paper Figs. 25-26, §5.1", dbw_steps.run),
        Experiment("dbw-takeover", "Manual/Automatic switching", "DBW paper Fig. 28, §5.2", takeover.run),
        Experiment("ares-fig15", "Lateral control: the MPC beside Stanley", "ARES paper Fig. 15, §3.6.1", lateral.run),
        Experiment(
            "ares-fig14", "Obstacle area: trapezoid beside rectangle", "ARES paper Fig. 14, §3.5.3", obstacle_zone.run
        ),
    )
}
