"""A short rendered sequence for a test module (made once per module by its fixture)."""

from __future__ import annotations

import pytest

from quadnav.experiments.datasets import make_dataset, sequence_spec
from quadnav.io.datasets import VisualInertialDataset, open_dataset


def rendered(
    factory: pytest.TempPathFactory, sequence: str, **spec: object
) -> VisualInertialDataset:
    """``sequence`` (a built-in one) made with ``spec``'s settings in a fresh folder, opened;
    ideal sensors unless ``spec`` says otherwise (these tests check plumbing and geometry: the
    estimator on realistic sensors is measured in the results)."""
    root = factory.mktemp(sequence) / sequence
    make_dataset(sequence_spec(sequence, {"sensors": "ideal", **spec}), root, name=sequence)
    return open_dataset(root)
