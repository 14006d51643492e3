"""Importers from other datasets' layouts into the SS-NeRF dataset format (`ssnerf-import`).

- `paper_llff`: the SS-NeRF authors' released Replica scenes (LLFF layout, all six properties);
- `semantic_nerf`: Semantic-NeRF's Replica renders (RGB, depth, semantics; `ssnerf-label` adds the rest).
"""

from ssnerf_method.importers.paper_llff import PaperLLFFImportConfig, import_paper_llff
from ssnerf_method.importers.semantic_nerf import SemanticNeRFImportConfig, import_semantic_nerf
from ssnerf_method.importers.writer import ImportSummary

__all__ = [
    "ImportSummary",
    "PaperLLFFImportConfig",
    "SemanticNeRFImportConfig",
    "import_paper_llff",
    "import_semantic_nerf",
]
