"""`ImportedWeights.require_fit`: the one key-and-shape check every official importer ends with."""

import pytest
import torch

from i2pbench.api import ImportedWeights, WeightsError

EXPECTED = {"a.weight": torch.zeros(2, 3), "a.bias": torch.zeros(2)}


def test_an_exact_fit_passes():
    ImportedWeights.require_fit({"a.weight": torch.ones(2, 3), "a.bias": torch.ones(2)}, EXPECTED, "x")


def test_each_misfit_is_named_in_order_missing_unexpected_shape():
    state = {"a.weight": torch.ones(3, 2), "b.bias": torch.ones(2)}
    with pytest.raises(WeightsError) as err:
        ImportedWeights.require_fit(state, EXPECTED, "f.pt is not the net")
    assert str(err.value) == (
        "f.pt is not the net: missing key a.bias; unexpected key b.bias; key a.weight: shape (3, 2), expected (2, 3)"
    )


def test_more_than_twelve_misfits_are_counted_not_listed():
    state = {f"extra{i}": torch.ones(1) for i in range(15)}
    with pytest.raises(WeightsError) as err:
        ImportedWeights.require_fit(state, {}, "f.pt")
    assert str(err.value).endswith("unexpected key extra11; and 3 more")
    assert "extra12" not in str(err.value)
