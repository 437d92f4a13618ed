from __future__ import annotations

import itertools

import pytest
import torch

from pasta.plan import SkillSpec, sample_structures, set_sizes

CUT, MOVE, MERGE = SkillSpec("cut", 1, 2), SkillSpec("move", 1, 1), SkillSpec("merge", 2, 1)


def _all_structures(sequence, k_obs):
    sizes = set_sizes(sequence, k_obs)
    per_step = [list(itertools.permutations(range(size), skill.n_in))
                for skill, size in zip(sequence, sizes[:-1], strict=True)]
    return set(itertools.product(*per_step))


def test_sampler_reaches_every_structure_of_small_sets():
    for sequence, k_obs in [((CUT, MOVE, MOVE), 1), ((MERGE, CUT, MOVE), 3), ((MOVE, MERGE), 4)]:
        structures = sample_structures(sequence, k_obs, 3000, torch.Generator().manual_seed(0))
        seen = {structures.structure(row) for row in range(structures.n_samples)}
        assert seen == _all_structures(sequence, k_obs), [s.name for s in sequence]


def test_sets_are_new_vectors_then_kept_entities_in_order():
    sequence = (MERGE, CUT, MOVE)
    st = sample_structures(sequence, 3, 200, torch.Generator().manual_seed(1))
    assert st.n_fixed == 3 and st.n_variables == 4
    for row in range(st.n_samples):
        current = list(range(3))
        for h, skill in enumerate(sequence):
            chosen = [int(i) for i in st.attention[h][row]]
            assert [int(i) for i in st.attended[h][row]] == [current[i] for i in chosen]
            kept = [u for i, u in enumerate(current) if i not in chosen]
            new = [int(i) for i in st.created[h]]
            assert len(new) == skill.n_out
            current = new + kept
            assert [int(i) for i in st.sets[h + 1][row]] == current


def test_sampling_is_seeded():
    a = sample_structures((CUT, MOVE, MOVE), 1, 50, torch.Generator().manual_seed(3))
    b = sample_structures((CUT, MOVE, MOVE), 1, 50, torch.Generator().manual_seed(3))
    assert all(torch.equal(x, y) for x, y in zip(a.attention, b.attention, strict=True))
    assert all(torch.equal(x, y) for x, y in zip(a.sets, b.sets, strict=True))
    other = sample_structures((CUT, MOVE, MOVE), 1, 50, torch.Generator().manual_seed(4))
    assert not all(torch.equal(x, y) for x, y in zip(a.attention, other.attention, strict=True))


def test_a_fixed_first_row_changes_only_sample_zero():
    sequence = (MERGE, CUT, MOVE)
    free = sample_structures(sequence, 3, 40, torch.Generator().manual_seed(2))
    fixed = sample_structures(sequence, 3, 40, torch.Generator().manual_seed(2), first_row=((2, 0), (1,)))
    assert fixed.structure(0)[:2] == ((2, 0), (1,))
    for h in range(len(sequence)):
        assert torch.equal(fixed.attention[h][1:], free.attention[h][1:])
    assert [int(i) for i in fixed.sets[1][0]] == [3, 1]  # the merged vector, then the kept entity 1
    assert [int(i) for i in fixed.attended[1][0]] == [1]


def test_a_bad_first_row_names_the_step_and_positions():
    with pytest.raises(ValueError, match=r"step 1: attended positions \(5,\)"):
        sample_structures((CUT, MOVE), 1, 4, torch.Generator().manual_seed(0), first_row=((0,), (5,)))
    with pytest.raises(ValueError, match="first_row has 3 steps, the sequence 2"):
        sample_structures((CUT, MOVE), 1, 4, torch.Generator().manual_seed(0), first_row=((0,), (0,), (0,)))
