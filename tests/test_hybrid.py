"""The Hybrid baseline's per-property encoder-decoders: their training losses fall on a generated scene, and they
annotate an RGB image in the model's prediction layout."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ssnerf_method.data.dataparser import SSNeRFDataParserConfig
from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.evaluation.hybrid import EncoderDecoder, HybridBaseline, HybridBaselineConfig
from ssnerf_method.evaluation.scoring import score_predictor
from ssnerf_method.properties import resolve_properties
from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene


@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    root = tmp_path_factory.mktemp("scene") / "scene"
    make_scene(MakeSceneConfig(output_dir=root, width=40, height=30, num_frames=10))
    parser = SSNeRFDataParserConfig(data=root).setup()
    return SSNeRFDataset(parser.get_dataparser_outputs("train")), SSNeRFDataset(parser.get_dataparser_outputs("test"))


def test_encoder_decoder_keeps_any_image_size() -> None:
    network = EncoderDecoder(out_channels=5, width=8, depth=3)
    assert network(torch.rand(2, 3, 30, 41)).shape == (2, 5, 30, 41)  # padded to a multiple of 8, then cropped


def test_losses_fall_and_predictions_have_the_model_layout(splits) -> None:
    torch.set_num_threads(1)
    train, test = splits
    specs = resolve_properties(list(train.metadata["available_properties"]))
    num_classes = len(train.metadata["semantic_classes"])
    hybrid = HybridBaseline(train, specs, num_classes, HybridBaselineConfig(width=8, steps=60, batch_size=4))
    history = hybrid.fit()
    assert set(history) == {spec.name for spec in specs if spec.file_key is not None}
    for name, losses in history.items():
        if name == "keypoints":  # a sparse map under L1 starts near its optimum (all zero): it may only plateau
            assert np.mean(losses[-10:]) < 1.05 * np.mean(losses[:5])
            continue
        assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:5]), name
    predictions = hybrid.predict_image(test[0]["image"])
    assert predictions["semantics"].shape == (30, 40, num_classes)  # logits
    assert predictions["normals"].shape == (30, 40, 3) and 0 <= predictions["normals"].min() <= 1
    assert predictions["edges"].shape == (30, 40, 1)
    # Annotating the true test images (a perfect NeRF) scores every property.
    scores = score_predictor(hybrid.predictor(lambda cameras, index: test[index]["image"]), test, specs, num_classes)
    assert all(np.isfinite(scores[name]) for name in ("semantics_miou", "normals_l1", "shading_l1", "edges_l1"))
