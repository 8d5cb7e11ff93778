"""Place recognition: a vocabulary tree over binary descriptors trained offline and shipped small,
bags of words with tf-idf weights and DBoW2's L1 score, a database with inverted and direct
indices, and DLoopDetector's normalised scores, islands and temporal consistency. It imports
vision and below only, and serves the loop closer and the SLAM.

Every name loads on first use (OpenCV only behind :func:`describe_image`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from quadnav.lazy import lazy_getattr

if TYPE_CHECKING:
    from quadnav.place.database import Database, DirectIndex, QueryResult
    from quadnav.place.detector import (
        Detection,
        DetectionStatus,
        Island,
        LoopDetector,
        LoopDetectorConfig,
    )
    from quadnav.place.features import describe_image
    from quadnav.place.train import train_vocabulary
    from quadnav.place.vocabulary import (
        BowVector,
        Vocabulary,
        default_vocabulary,
        l1_score,
        load_vocabulary,
    )

__all__ = [
    "BowVector",
    "Database",
    "Detection",
    "DetectionStatus",
    "DirectIndex",
    "Island",
    "LoopDetector",
    "LoopDetectorConfig",
    "QueryResult",
    "Vocabulary",
    "default_vocabulary",
    "describe_image",
    "l1_score",
    "load_vocabulary",
    "train_vocabulary",
]

_WHERE: dict[str, str] = {
    "BowVector": "quadnav.place.vocabulary",
    "Database": "quadnav.place.database",
    "Detection": "quadnav.place.detector",
    "DetectionStatus": "quadnav.place.detector",
    "DirectIndex": "quadnav.place.database",
    "Island": "quadnav.place.detector",
    "LoopDetector": "quadnav.place.detector",
    "LoopDetectorConfig": "quadnav.place.detector",
    "QueryResult": "quadnav.place.database",
    "Vocabulary": "quadnav.place.vocabulary",
    "default_vocabulary": "quadnav.place.vocabulary",
    "describe_image": "quadnav.place.features",
    "l1_score": "quadnav.place.vocabulary",
    "load_vocabulary": "quadnav.place.vocabulary",
    "train_vocabulary": "quadnav.place.train",
}


__getattr__ = lazy_getattr(__name__, _WHERE)


def __dir__() -> list[str]:
    return sorted(__all__)
