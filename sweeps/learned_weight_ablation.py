"""The learned weight's input ablation (sweeps/learned-weight-ablation.toml): ``learned_weight`` with one of its
inputs fed as 0, each registered as its own planner so a comparison trains and tests it like any other.

``learned_weight_without_direction`` drops cos θ, ``learned_weight_without_closing`` tanh c and
``learned_weight_without_clearance`` d/d_s (:class:`jaxapf.planners.LearnedWeight`, ``inputs``).
"""

from jaxapf.planners import APF, LearnedWeight, register_planner
from jaxapf.planners.learned import FEATURES

for dropped in FEATURES:
    register_planner(f"learned_weight_without_{dropped}",
                     APF(LearnedWeight(inputs=tuple(f for f in FEATURES if f != dropped)),
                         description=f"the learned weight ω_θ with its {dropped} input fed as 0 (an ablation)"),
                     replace=True)
