"""The numbers of the PASTA appendix (CoRL 2022), copied as printed, to put beside ours.

Only what the appendix states is here. Fig. 2 (planning time and performance against the number of
samples, CutRearrange) is a plot without printed values, so it has no entry; the main paper's per-task
results table is not part of the appendix, so :data:`MAIN` holds only the two tasks whose PASTA result
the appendix states in words or in a table.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType


@dataclass(frozen=True)
class PaperScore:
    """A normalised performance and a success rate (fraction of the 5 test configurations)."""

    performance: float
    success_rate: float
    printed: str  # "performance / success" exactly as the appendix prints them ("0.360 / 20%", "0.90 / 5/5")

    def cell(self) -> str:
        return self.printed


@dataclass(frozen=True)
class PaperMeanStd:
    mean: float
    std: float

    def cell(self) -> str:
        return f"{self.mean:.3f} ± {self.std:.3f}"


# Appendix Table 5: "Additional ablation results from CutRearrange" (Performance / Success), in the
# table's row order. Flat3D is a baseline of the main paper, not a row of Table 5.
TABLE5 = MappingProxyType({
    "no_smoothing_feasibility": PaperScore(0.744, 0.40, "0.744 / 40%"),
    "shared_encoder_policy": PaperScore(-0.304, 0.0, "-0.304 / 0%"),
    "tool_concat_policy": PaperScore(0.516, 0.60, "0.516 / 60%"),
    "set_without_filtering": PaperScore(0.360, 0.20, "0.360 / 20%"),
    "pasta": PaperScore(0.837, 0.80, "0.837 / 80%"),
})

# Appendix Table 6: planning time of PASTA in seconds (CRS-Twice with receding-horizon planning).
TABLE6_PLANNING_TIME_S = MappingProxyType({
    "LiftSpread": 58.0,
    "GatherMove": 35.0,
    "CutRearrange": 35.0,
    "CRS": 307.0,
    "CRS-Twice": 7810.0,
})

# Appendix Table 7: EMD(planned goal, ground-truth goal) and EMD(reached goal, ground-truth goal),
# mean ± std over 4 *real-world* trajectories per task.
TABLE7_EMD_PLANNED = MappingProxyType({
    "CutRearrange": PaperMeanStd(0.038, 0.004),
    "CRS": PaperMeanStd(0.027, 0.004),
    "CRS-Twice": PaperMeanStd(0.029, 0.002),
})
TABLE7_EMD_REACHED = MappingProxyType({
    "CutRearrange": PaperMeanStd(0.056, 0.007),
    "CRS": PaperMeanStd(0.044, 0.006),
    "CRS-Twice": PaperMeanStd(0.054, 0.016),
})

# Appendix Table 8: PASTA on CRS against the planning horizon (success as "k/5").
TABLE8_HORIZON = MappingProxyType({
    3: PaperScore(0.896, 1.0, "0.896 / 5/5"),
    4: PaperScore(0.866, 0.8, "0.866 / 4/5"),
    5: PaperScore(0.90, 1.0, "0.90 / 5/5"),
    6: PaperScore(0.878, 0.8, "0.878 / 4/5"),
})

# Appendix §4.5 "Robust to distractors": CRS with 2 distractor pieces, and without (0 distractors).
DISTRACTORS = MappingProxyType({
    0: PaperScore(0.896, 1.0, "0.896 / 100%"),
    2: PaperScore(0.879, 1.0, "0.879 / 100%"),
})

# PASTA's per-task result where the appendix states it: CutRearrange from Table 5 (PASTA row),
# CRS from §4.5 (without distractors; also Table 8 at horizon 3).
MAIN = MappingProxyType({
    "CutRearrange": TABLE5["pasta"],
    "CRS": DISTRACTORS[0],
})
