"""The input checks: a finite check that reads a sum must still catch every NaN and infinity,
and must not take finite values whose sum overflows for non-finite ones."""

from __future__ import annotations

import pytest
import torch

from sfb_video.errors import MeshError, SfbError, check_finite


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_single_non_finite_value_is_caught(bad: float) -> None:
    x = torch.rand(3, 100, 100)
    x[1, 50, 7] = bad
    with pytest.raises(SfbError, match="texture contains NaN or infinite values"):
        check_finite(x, "texture")
    with pytest.raises(MeshError):
        check_finite(x, "mesh vertices", MeshError)


def test_infinities_that_cancel_in_a_sum_are_caught() -> None:
    with pytest.raises(SfbError):
        check_finite(torch.tensor([float("inf"), -float("inf"), 1.0]), "x")


def test_finite_values_whose_sum_overflows_pass() -> None:
    check_finite(torch.tensor([3e38, 3e38, 3e38]), "x")
    check_finite(torch.rand(642, 3), "x")
