"""``stcgym sweep``: classical controllers over random plant families.

:mod:`~stcgym.envs.families` draws the plants; :mod:`~stcgym.agents.sweeps.config`
checks a sweep's settings; :mod:`~stcgym.agents.sweeps.chunk` runs one task's lanes in closed
loop; :mod:`~stcgym.agents.sweeps.sweep` runs the tasks (resumable) and writes the table and
the robustness map; :mod:`~stcgym.agents.sweeps.cli` is the command line.
"""

from stcgym.agents.sweeps.config import SweepConfig, SweepError
from stcgym.agents.sweeps.sweep import SweepResult, read_table, robustness_map, run_sweep

__all__ = ["SweepConfig", "SweepError", "SweepResult", "read_table", "robustness_map", "run_sweep"]
