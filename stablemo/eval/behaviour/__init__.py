"""The behaviour suite: does a generated motion do what its prompt says?

R-precision asks whether a motion is nearer its own text than 31 others; it cannot see the right
hand, the count, the turn angle or the order of a composite. Here each prompt of a table (table.py,
prompts.yaml) is generated at several lengths and seeds (runner.py) and checked from the joints
(measures.py -> checks.py); summary.py gives pass rates with Wilson intervals, truth.py the
synthetic generator's own motions on which every check is validated, report.py the docs' table and
picture. `stablemo behaviour` (stablemo.cli.behaviour) runs it.
"""

from stablemo.eval.behaviour.checks import Verdict, score
from stablemo.eval.behaviour.runner import (
           pipeline_generator,
           run_suite,
           truth_generator,
)
from stablemo.eval.behaviour.summary import format_table, summarize, wilson
from stablemo.eval.behaviour.table import ATTRIBUTES, Prompt, load_prompts

__all__ = ["ATTRIBUTES", "Prompt", "Verdict", "format_table", "load_prompts", "pipeline_generator", "run_suite",
           "score", "summarize", "truth_generator", "wilson"]
