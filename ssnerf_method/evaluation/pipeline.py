"""The SS-NeRF pipeline's old home: config.yml files of runs trained before it moved to `pipelines/` name it here."""

from ssnerf_method.pipelines.ssnerf_pipeline import SSNeRFPipeline, SSNeRFPipelineConfig, TrainingDiverged

__all__ = ["SSNeRFPipeline", "SSNeRFPipelineConfig", "TrainingDiverged"]
