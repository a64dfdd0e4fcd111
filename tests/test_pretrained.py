"""The shipped pretrained model: loads safely, holds only network weights, reproduces its card."""

from __future__ import annotations

import pytest
import torch

from arteq.pretrained import PRETRAINED_DIR, available, resolve_checkpoint

pytestmark = pytest.mark.skipif("anny22" not in available(), reason="no shipped anny22 model in this tree")


SHIPPED = available()


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_file_is_weights_only_and_small(name):
    path = resolve_checkpoint(name)
    assert path.parent == PRETRAINED_DIR
    assert path.stat().st_size < 8 * 2**20
    state = torch.load(str(path), map_location="cpu", weights_only=True)
    assert set(state) >= {"state_dict", "hyper_parameters", "arteq"}
    assert "optimizer_states" not in state and "loops" not in state
    assert all(k.startswith("net.") for k in state["state_dict"]), "body-model data must not be shipped"
    assert (PRETRAINED_DIR / f"{name}.md").is_file()


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_model_reproduces_its_card_subset_metrics(name):
    from arteq.pretrained.card import load_module, reproduces, subset_metrics

    path = resolve_checkpoint(name)
    info = torch.load(str(path), map_location="cpu", weights_only=True)["arteq"]
    got = subset_metrics(load_module(name), int(info["subset_n"]))
    tol = float(info["subset_tolerance"])
    for split, values in info["subset_metrics"].items():
        for key, value in values.items():
            assert reproduces(value, got[split][key], tol), (split, key, got[split][key], value)


def test_unknown_name_is_a_clear_error():
    with pytest.raises(FileNotFoundError, match="no pretrained model of that name"):
        resolve_checkpoint("no_such_model")
