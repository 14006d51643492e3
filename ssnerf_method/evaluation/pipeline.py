"""Where the SS-NeRF pipeline lived before it moved to `ssnerf_method/pipelines/ssnerf_pipeline.py`: the config.yml
of every run trained before then names `ssnerf_method.evaluation.pipeline.SSNeRFPipelineConfig`, and `ns-eval`,
`ns-render` and `ns-viewer` load those runs through this name."""

from ssnerf_method.pipelines.ssnerf_pipeline import SSNeRFPipeline, SSNeRFPipelineConfig, TrainingDiverged

__all__ = ["SSNeRFPipeline", "SSNeRFPipelineConfig", "TrainingDiverged"]
