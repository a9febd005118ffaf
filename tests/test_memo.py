"""The bounded memo behind the layout caches: built once per key, oldest out past its size."""

import pytest

from abrdf_jax._memo import BoundedMemo


def test_bounded_memo_builds_once_and_drops_the_oldest():
    built = []

    def build(k):
        built.append(k)
        return k * 10

    memo = BoundedMemo(2)
    assert memo.get(1, lambda: build(1)) == 10
    assert memo.get(1, lambda: build(1)) == 10
    assert built == [1]
    memo.get(2, lambda: build(2))
    memo.get(3, lambda: build(3))  # 1 is the oldest: dropped
    assert len(memo) == 2
    assert memo.get(1, lambda: build(1)) == 10 and built == [1, 2, 3, 1]
    memo.clear()
    assert len(memo) == 0
    with pytest.raises(ValueError, match="maxsize"):
        BoundedMemo(0)


def test_a_failed_build_caches_nothing():
    memo = BoundedMemo(4)

    def fail():
        raise RuntimeError("no")

    with pytest.raises(RuntimeError):
        memo.get("k", fail)
    assert len(memo) == 0
