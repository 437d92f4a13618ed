"""Masses carried through a plan: each step hands its attended mass to its new entities."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pasta.evaluate.plan_masses import carried_masses, observed_masses, plan_masses
from pasta.plan import Plan


def test_observed_masses_are_the_shares_of_the_labelled_points():
    labels = np.array([0, 0, 0, 1, -1, 1, 0, 0])
    assert observed_masses(labels, 2).tolist() == pytest.approx([5 / 7, 2 / 7])
    with pytest.raises(ValueError, match="0 .. 2"):
        observed_masses(np.array([0, 3]), 3)


def test_a_cut_splits_by_volume_and_push_and_spread_keep_the_mass_they_were_handed():
    # CRS: cut the whole (mass 1) into pieces of decoded volumes 3 and 1, push the second new entity,
    # spread the pushed one (which now stands first); a spread decoded twice as big keeps its mass.
    masses = carried_masses([(0,), (1,), (0,)], np.array([1.0]),
                            [np.array([3.0, 1.0]), np.array([5.0]), np.array([10.0])])
    assert [m.tolist() for m in masses] == [pytest.approx([1.0]), pytest.approx([0.75, 0.25]),
                                            pytest.approx([0.25, 0.75]), pytest.approx([0.25, 0.75])]


def test_a_merge_gets_the_sum_and_unattended_entities_keep_theirs_in_order():
    masses = carried_masses([(2, 0)], np.array([0.5, 0.2, 0.3]), [np.array([0.1])])
    assert masses[1].tolist() == pytest.approx([0.8, 0.2])


def test_new_entities_without_volume_share_equally_and_bad_steps_are_named():
    assert carried_masses([(0,)], np.array([1.0]), [np.zeros(2)])[1].tolist() == pytest.approx([0.5, 0.5])
    with pytest.raises(ValueError, match=r"step 1 attends \[1\]"):
        carried_masses([(1,)], np.array([1.0]), [np.ones(1)])
    with pytest.raises(ValueError, match="2 steps of attention but 1"):
        carried_masses([(0,), (0,)], np.array([1.0]), [np.ones(1)])


def test_plan_masses_decodes_only_each_steps_new_entities():
    # Latents whose first coordinate is the size of a decoded cube: the cut's pieces 2 and 1 wide (volumes 8, 1).
    def decode(latents: torch.Tensor) -> np.ndarray:
        corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)
        return np.stack([corners * float(u[0]) for u in latents])

    sets = (torch.tensor([[4.0, 0, 0, 0]]), torch.tensor([[2.0, 0, 0, 0], [1.0, 0, 0, 0]]),
            torch.tensor([[7.0, 0, 0, 0], [2.0, 0, 0, 0]]))
    plan = Plan(skills=("cut", "push"), attention=((0,), (1,)), latent_sets=sets, feasibilities=(1.0, 1.0),
                cost=0.0, score=0.0, planning_time_s=0.0)
    masses = plan_masses(plan, decode, np.array([1.0]))
    assert masses[1].tolist() == pytest.approx([8 / 9, 1 / 9])
    assert masses[2].tolist() == pytest.approx([1 / 9, 8 / 9])
