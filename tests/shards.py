"""The suite cut into parts for CI's job matrix (``python -m pytest --shard K/N``, .github/workflows/build.yml).

A part takes whole xdist groups (tests/conftest.py): the shared built tree's tests stay on one runner, which builds
that tree once, and so do the shared lab's. The built tree's group is the suite's longest path (its cold build and the
README's commands, one after the other) and has part 1 to itself but for what it leaves its second process; the lab's
has part 2; every other group (a module) is dealt in turn, from part 3 on, so that each part gets its share of modules.
Every test is in exactly one part, and which one does not depend on the order of collection.
"""

from __future__ import annotations

from collections.abc import Iterable

BUILT_TREE, SHARED_LAB = "built_tree", "shared_lab"


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` -> (K, N), 1 <= K <= N."""
    try:
        part, count = (int(x) for x in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard {text!r}: write it as K/N, e.g. 2/4") from None
    if not 1 <= part <= count:
        raise ValueError(f"--shard {text!r}: K must be between 1 and N")
    return part, count


def assign_shards(groups: Iterable[str], count: int) -> dict[str, int]:
    """Each group's part (1..count): the built tree's 1, the shared lab's 2, the others in sorted order dealt from
    part 3 (or from 1 where there are fewer parts), each part in turn."""
    pinned = {BUILT_TREE: 1, SHARED_LAB: min(2, count)}
    others = sorted(set(groups) - set(pinned))
    start = 2 if count > 2 else 0
    shards = {group: shard for group, shard in pinned.items() if group in set(groups)}
    for k, group in enumerate(others):
        shards[group] = (start + k) % count + 1
    return shards
