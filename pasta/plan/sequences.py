"""Skills as entity counts, and the skill sequences that take the observed entity count to the goal's."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["NoSkillSequenceError", "SkillSpec", "enumerate_sequences", "resolve_sequence", "set_sizes"]


@dataclass(frozen=True)
class SkillSpec:
    """A skill as the planner sees it: it takes ``n_in`` entities and gives ``n_out`` new ones."""

    name: str
    n_in: int
    n_out: int

    def __post_init__(self) -> None:
        if self.n_in < 1 or self.n_out < 1:
            raise ValueError(f"skill {self.name!r} needs n_in, n_out >= 1, got {self.n_in} -> {self.n_out}")


def set_sizes(sequence: Sequence[SkillSpec], k_obs: int) -> tuple[int, ...]:
    """Entity counts ``K_0 .. K_H`` along ``sequence`` from ``k_obs`` entities.

    Raises:
        ValueError: when a step takes more entities than the set then holds.
    """
    sizes = [k_obs]
    for h, skill in enumerate(sequence, start=1):
        if skill.n_in > sizes[-1]:
            names = [s.name for s in sequence]
            raise ValueError(f"step {h} ({skill.name}) of {names} takes {skill.n_in} entities but U^{h - 1} "
                             f"holds {sizes[-1]}")
        sizes.append(sizes[-1] - skill.n_in + skill.n_out)
    return tuple(sizes)


class NoSkillSequenceError(ValueError):
    """No sequence of the task's skills takes the observed entity count to the goal's in the horizon."""


def enumerate_sequences(skills: Sequence[SkillSpec], horizon: int, k_obs: int, k_goal: int
                        ) -> list[tuple[SkillSpec, ...]]:
    """All sequences of ``horizon`` skills whose net change ``sum(n_out - n_in)`` is ``k_goal - k_obs``.

    Sequences come in lexicographic order of the skills' indices; a sequence that would take more
    entities than the set holds at some step is left out.

    Raises:
        NoSkillSequenceError: naming the counts and the skills when no sequence qualifies.
    """
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon}")
    if k_obs < 1 or k_goal < 1:
        raise ValueError(f"need at least one observed and one goal entity, got {k_obs} and {k_goal}")
    found = []
    for sequence in itertools.product(skills, repeat=horizon):
        if sum(s.n_out - s.n_in for s in sequence) != k_goal - k_obs:
            continue
        try:
            set_sizes(sequence, k_obs)
        except ValueError:
            continue
        found.append(sequence)
    if not found:
        described = ", ".join(f"{s.name} ({s.n_in}->{s.n_out})" for s in skills)
        raise NoSkillSequenceError(f"no skill sequence of horizon {horizon} takes {k_obs} entities to {k_goal} "
                         f"(net change {k_goal - k_obs:+d}); skills: {described}")
    return found


def resolve_sequence(skills: Sequence[SkillSpec], names: Sequence[str], k_obs: int | None = None
                     ) -> tuple[SkillSpec, ...]:
    """The specs of the named skills.

    A skill with several arities (specs of one name with different ``n_in``, such as a gather of 1, 2 or 3
    pieces) takes the most entities the set then holds, which needs ``k_obs``, the entity count the
    sequence starts from.

    Raises:
        KeyError: naming an unknown skill and the known ones.
        ValueError: when a skill with several arities is named without ``k_obs``, or none of its arities
            fits the set.
    """
    by_name: dict[str, list[SkillSpec]] = {}
    for spec in skills:
        by_name.setdefault(spec.name, []).append(spec)
    unknown = [name for name in names if name not in by_name]
    if unknown:
        raise KeyError(f"unknown skill {unknown[0]!r}; known: {sorted(by_name)}")
    chosen: list[SkillSpec] = []
    size = k_obs
    for h, name in enumerate(names, start=1):
        options = by_name[name]
        if len(options) > 1:
            if size is None:
                raise ValueError(f"skill {name!r} takes {sorted(s.n_in for s in options)} entities: "
                                 f"resolving it needs the observed entity count k_obs")
            fitting = [s for s in options if s.n_in <= size]
            if not fitting:
                raise ValueError(f"step {h} ({name}) takes at least {min(s.n_in for s in options)} entities but "
                                 f"the set then holds {size}")
            options = [max(fitting, key=lambda s: s.n_in)]
        chosen.append(options[0])
        if size is not None:
            size = size - options[0].n_in + options[0].n_out
    return tuple(chosen)
