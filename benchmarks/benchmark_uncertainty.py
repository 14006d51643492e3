"""Does `semantics_uncertainty` point at the pixels whose class is wrong? Test views of trained SS-NeRF runs.

    python -m benchmarks.benchmark_uncertainty --load-configs RUN/config.yml [RUN2/config.yml ...] \
        [--output reports/uncertainty.json]

For each run, over the labelled pixels of its test views: the share of pixels whose most likely class is wrong, the
AUROC of the uncertainty as a detector of those pixels (the chance that a wrong pixel is more uncertain than a right
one: 0.5 for a map that knows nothing), and the share of the wrong pixels among the most uncertain fifth of all pixels
(0.2 for a map that knows nothing), beside both figures for a random map, so that the numbers can be read as better or
no better than chance. Meant for runs trained on sparse labels (`ssnerf-study propagation` keeps them under
`OUTPUT/runs/`), where the uncertainty is what tells a person where to paint the next stroke.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List

import numpy as np
import tyro
from scipy.stats import rankdata

from nerfstudio.utils.eval_utils import eval_setup
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.io import write_json_atomic
from ssnerf_method.experiments.propagation import model_predictor
from ssnerf_method.properties import class_property, class_uncertainty


@dataclass
class BenchmarkUncertaintyConfig:
    """How well the class uncertainty finds the wrongly classified test pixels of trained runs."""

    load_configs: List[Path] = field(default_factory=list)
    """`config.yml` of each trained run (with semantics)."""
    output: Path = Path("reports/uncertainty.json")
    """Where the figures are written (JSON)."""
    top_share: float = 0.2
    """The most uncertain share of the pixels in which the wrong ones are counted."""
    seed: int = 0
    """Seed of the random map that the figures are set beside."""


def detection(uncertainty: np.ndarray, wrong: np.ndarray, top_share: float) -> Dict[str, float]:
    """AUROC of `uncertainty` as a detector of `wrong` (ties count half, as the rank-sum statistic counts them) and
    the share of the wrong pixels among the `top_share` most uncertain."""
    count_wrong, count_right = int(wrong.sum()), int((~wrong).sum())
    if count_wrong == 0 or count_right == 0:
        return {"auroc": float("nan"), "wrong_in_top": float("nan")}
    ranks = rankdata(uncertainty)  # tied values share their mean rank
    auroc = (ranks[wrong].sum() - count_wrong * (count_wrong + 1) / 2) / (count_wrong * count_right)
    top = np.argsort(-uncertainty, kind="stable")[: max(1, int(round(top_share * len(uncertainty))))]
    return {"auroc": float(auroc), "wrong_in_top": float(wrong[top].sum() / count_wrong)}


def score_run(config: Path, top_share: float, seed: int) -> Dict[str, float]:
    """The figures of one run's test views (`detection`), and the same for a random map."""
    _, pipeline, _, _ = eval_setup(config, test_mode="test")
    spec = class_property()
    test = pipeline.datamanager.eval_dataset
    num_classes = pipeline.model.num_classes
    predict = model_predictor(pipeline)
    uncertainties, wrongs = [], []
    for index in range(len(test)):
        logits = predict(test.cameras, index)[spec.name].float()
        label = spec.label(test[index], num_classes)
        valid = spec.kind.valid(label)
        uncertainties.append(class_uncertainty(logits)[..., 0][valid].numpy())
        wrongs.append((logits.argmax(dim=-1) != label[..., 0].long())[valid].numpy())
    uncertainty, wrong = np.concatenate(uncertainties), np.concatenate(wrongs)
    chance = np.random.default_rng(seed).random(len(wrong))
    return {"test_pixels": int(len(wrong)), "wrong_share": float(wrong.mean()),
            **detection(uncertainty, wrong, top_share),
            **{f"random_{key}": value for key, value in detection(chance, wrong, top_share).items()}}


def main(config: BenchmarkUncertaintyConfig) -> Dict[str, Dict[str, float]]:
    if not config.load_configs:
        raise SystemExit("benchmark_uncertainty: no run given; pass --load-configs RUN/config.yml ...")
    results = {str(path): score_run(path, config.top_share, config.seed) for path in config.load_configs}
    for path, figures in results.items():
        CONSOLE.print(f"{path}: {figures['wrong_share']:.1%} of the test pixels wrong; uncertainty AUROC "
                      f"{figures['auroc']:.3f} (random {figures['random_auroc']:.3f}), wrong pixels in the most "
                      f"uncertain {config.top_share:.0%}: {figures['wrong_in_top']:.1%} "
                      f"(random {figures['random_wrong_in_top']:.1%})")
    write_json_atomic(config.output, {"top_share": config.top_share, "runs": results})
    CONSOLE.print(f"written: {config.output}")
    return results


def entrypoint() -> None:
    main(tyro.cli(BenchmarkUncertaintyConfig))


if __name__ == "__main__":
    entrypoint()
