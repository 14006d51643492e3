"""Sphinx extension of the SS-NeRF docs: tables read from the code at build time, never written by hand.

- ``ssnerf-registry``: one row per property of `ssnerf_method.properties.REGISTRY` (label key, kind, decoder branch,
  loss and weight, reported metrics, display, weak-label corruption, label maker).
- ``ssnerf-methods``: the registered methods (`ssnerf`, `ssnerf-lite`): description, steps, rays per batch, and every
  model option in which they differ from each other.
- An ``autodoc-process-docstring`` hook: the package's docstrings are Markdown-flavoured plain text (`code` in single
  backticks, `*bs` in shapes, "- " lists); they are turned into reStructuredText that cannot misparse (code as
  literals, everything else escaped, each paragraph or list item on one line).
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any, Dict, List, Sequence

from docutils import nodes
from docutils.parsers.rst import Directive
from sphinx.application import Sphinx


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> nodes.table:
    """A docutils table of text cells; a cell's `code` spans become literals."""
    group = nodes.tgroup(cols=len(headers))
    group += [nodes.colspec(colwidth=1) for _ in headers]
    head, body = nodes.thead(), nodes.tbody()
    for target, cells in ((head, [headers]), (body, rows)):
        for cells_of_row in cells:
            row = nodes.row()
            for text in cells_of_row:
                entry = nodes.entry()
                entry += paragraph(text)
                row += entry
            target += row
    group += head
    group += body
    result = nodes.table()
    result += group
    return result


def paragraph(text: str) -> nodes.paragraph:
    """`text` with its `code` spans as literals."""
    node = nodes.paragraph()
    for index, part in enumerate(str(text).split("`")):
        if part:
            node += nodes.literal(part, part) if index % 2 else nodes.Text(part)
    return node


def first_sentence(text: str | None) -> str:
    words = " ".join((text or "").split())
    return words.split(". ")[0].rstrip(".")


class RegistryTable(Directive):
    """The property registry as a table."""

    def run(self) -> List[nodes.Node]:
        from ssnerf_method.metrics import METRICS
        from ssnerf_method.properties import REGISTRY

        headers = ["property", "label in transforms.json", "kind", "decoder", "loss (weight λ)", "metrics reported",
                   "display", "weak labels", "label maker"]
        rows = []
        for spec in REGISTRY.values():
            activation = getattr(spec.kind, "activation_name", None)
            metrics = ", ".join(f"`{spec.metric_prefix}{key}` {'↑' if higher else '↓'}"
                                for key, higher in METRICS[spec.metric].reported)
            maker = spec.label_maker
            rows.append([
                f"`{spec.name}` ({spec.short})",
                f"`{spec.file_key}`" if spec.file_key else "the frame's image",
                f"`{type(spec.kind).__name__}`" + (f", {activation}" if activation else ""),
                {"v": "F_dec^v (view-dependent)", "nv": "F_dec^nv (view-independent)"}[spec.branch],
                f"`{spec.loss}` ({spec.weight:g})",
                metrics,
                spec.colormap,
                spec.corruption,
                f"`{type(maker).__name__}`: {maker.help}" if maker is not None else "–",
            ])
        return [table(headers, rows)]


def differing_options(configs: Sequence[Any]) -> Dict[str, List[Any]]:
    """Field name -> the values of every config in `configs` (dataclasses of one type), where they differ."""
    names = [field.name for field in dataclasses.fields(configs[0]) if not field.name.startswith("_")]
    values = {name: [getattr(config, name) for config in configs] for name in names}
    return {name: row for name, row in values.items() if any(repr(value) != repr(row[0]) for value in row)}


class MethodsTable(Directive):
    """The registered methods, side by side: trainer settings and the model options that differ."""

    def run(self) -> List[nodes.Node]:
        from ssnerf_method.method_configs import ssnerf, ssnerf_lite

        methods = [ssnerf, ssnerf_lite]
        configs = [method.config for method in methods]
        rows = [["description", *(method.description for method in methods)],
                ["training steps (`--max-num-iterations`)", *(f"{config.max_num_iterations:,}" for config in configs)],
                ["rays per step", *(str(config.pipeline.datamanager.train_num_rays_per_batch) for config in configs)],
                ["optimisers (learning rate → final rate over steps)", *(
                    "; ".join(f"{group}: {opt['optimizer'].lr:g} → {opt['scheduler'].lr_final:g} over "
                              f"{opt['scheduler'].max_steps:,}" for group, opt in config.optimizers.items())
                    for config in configs)]]
        for name, values in differing_options([config.pipeline.model for config in configs]).items():
            rows.append([f"`--pipeline.model.{name.replace('_', '-')}`", *(f"`{value!r}`" for value in values)])
        return [table(["", *(f"`{config.method_name}`" for config in configs)], rows)]


CODE = re.compile(r"(`+)(.+?)\1")
SPECIAL = re.compile(r"([\\*_|`\[\]<>])")


def rst_line(text: str) -> str:
    """One line of Markdown-flavoured text as safe reStructuredText: code spans as literals, the rest escaped."""
    out, last = [], 0
    for match in CODE.finditer(text):
        out.append(SPECIAL.sub(r"\\\1", text[last:match.start()]))
        out.append(f"``{match.group(2).strip()}``" if match.group(2).strip() else "")
        last = match.end()
    out.append(SPECIAL.sub(r"\\\1", text[last:]))
    return "".join(out)


def docstring_to_rst(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: List[str]) -> None:
    """Rewrite `lines` in place: each paragraph and each "- " list item joined on one line and escaped."""
    blocks: List[List[str]] = []
    current: List[str] = []
    for line in lines + [""]:
        stripped = line.strip()
        if not stripped:
            if current:
                blocks.append(current)
            current = []
        elif stripped.startswith("- ") and current:
            blocks.append(current)
            current = [stripped]
        else:
            current.append(stripped)
    result: List[str] = []
    for block in blocks:
        text = " ".join(block)
        item = text.startswith("- ")
        result += [("- " + rst_line(text[2:])) if item else rst_line(text), ""]
    lines[:] = result


def setup(app: Sphinx) -> Dict[str, Any]:
    app.add_directive("ssnerf-registry", RegistryTable)
    app.add_directive("ssnerf-methods", MethodsTable)
    app.connect("autodoc-process-docstring", docstring_to_rst)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
