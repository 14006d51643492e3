"""The viewer's Label panel: paint classes on the render, and every painted pixel becomes a labelled ray.

A click paints a brush disc, a drag a box, as rays of the viewer's camera at the training images' height; each stroke
is saved at once (`data/strokes.py`). `ns-train` mixes them into every batch; `ns-viewer` keeps them for the next run.
"Next suggested click" asks the questions `ssnerf-label --suggest-clicks` wrote (`questions.py`): a marker on the
surface asked about, the model's guess picked; "Answer" saves the class picked as a one-ray stroke, "Skip" moves on.
Everything a client sends is checked before anything is written (`refusal`).
"""

from __future__ import annotations

from typing import Callable, List, Optional, Sequence

import numpy as np
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.utils.rich_utils import CONSOLE
from nerfstudio.viewer.viewer_elements import (
    ViewerButton,
    ViewerClick,
    ViewerControl,
    ViewerDropdown,
    ViewerRectSelect,
    ViewerRGB,
    ViewerSlider,
    ViewerText,
)

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.strokes import Stroke, StrokeStore, WorldFrame, stroke_from_pixels
from ssnerf_method.viewer.questions import Question, Questions

OFF, BRUSH, BOX = "off", "brush: click", "box: drag"
"""The "Paint" choices: viewer navigation as usual, a disc per click, a box per drag."""
NO_CLASS = "(add a class first)"
"""The class picker's only entry while the dataset has no class."""
MAX_RAYS_PER_STROKE = 4096
"""A larger box is painted on a regular subgrid of its pixels (neighbouring rays say the same thing)."""
BRUSH_RADII = (1, 32)
"""The brush slider's range (pixels); a client message outside it is refused."""
MAX_CLASS_NAME = 64
"""Longest class name the panel adds (characters)."""
MARKER = "/ssnerf_question"
"""Scene node of the marker on the surface a suggested click asks about."""
VISER_SCALE = 10.0
"""nerfstudio's viewer draws the scene at this scale (`VISER_NERFSTUDIO_SCALE_RATIO`)."""


def outside_image(*positions: Sequence[float]) -> bool:
    """Whether a screen position (fractions of the image's width and height) from a client is not a point of the
    image: outside [0, 1] x [0, 1], not a pair, or not finite."""
    for position in positions:
        try:
            x, y = (float(value) for value in position)
        except (TypeError, ValueError):
            return True
        if not (0.0 <= x <= 1.0 and 0.0 <= y <= 1.0):  # (NaN fails both)
            return True
    return False


def disc_pixels(centre: Sequence[float], radius: float, width: int, height: int) -> np.ndarray:
    """(N, 2) pixel (column, row) of the pixels whose centre lies within `radius` of `centre` (pixel units, the
    image's top-left corner at 0); at least the pixel holding the centre."""
    columns, rows = np.meshgrid(np.arange(width), np.arange(height))
    inside = (columns + 0.5 - centre[0]) ** 2 + (rows + 0.5 - centre[1]) ** 2 <= radius**2
    pixels = np.stack([columns[inside], rows[inside]], axis=-1)
    if not len(pixels):
        pixels = np.array([[min(max(int(centre[0]), 0), width - 1), min(max(int(centre[1]), 0), height - 1)]])
    return pixels


def box_pixels(corner_min: Sequence[float], corner_max: Sequence[float], width: int, height: int) -> np.ndarray:
    """(N, 2) pixel (column, row) of the pixels whose centre lies in the box (fractions of the image), on a subgrid
    when there are more than `MAX_RAYS_PER_STROKE`."""
    x0, x1 = sorted((corner_min[0] * width, corner_max[0] * width))
    y0, y1 = sorted((corner_min[1] * height, corner_max[1] * height))
    columns = np.arange(max(int(np.ceil(x0 - 0.5)), 0), min(int(np.floor(x1 - 0.5)), width - 1) + 1)
    rows = np.arange(max(int(np.ceil(y0 - 0.5)), 0), min(int(np.floor(y1 - 0.5)), height - 1) + 1)
    stride = max(1, int(np.ceil(np.sqrt(len(columns) * len(rows) / MAX_RAYS_PER_STROKE))))
    grid = np.meshgrid(columns[::stride], rows[::stride])
    return np.stack([grid[0].ravel(), grid[1].ravel()], axis=-1)


class LabelPanel(nn.Module):
    """Class picker, brush size, "Add class", "Undo last stroke" and a paint switch (no parameters: nothing enters
    the checkpoint). `on_new_class` is told the class list after a class is added."""

    def __init__(
        self,
        store: StrokeStore,
        frame: WorldFrame,
        class_names: Sequence[str],
        num_slots: int,
        palette: Float[Tensor, "slots 3"],
        image_height: int,
        training: bool,
        on_new_class: Callable[[List[str]], None] = lambda names: None,
    ) -> None:
        super().__init__()
        self.store, self.frame = store, frame
        self.class_names = list(class_names)
        self.num_slots, self.image_height, self.training_run = num_slots, image_height, training
        self.palette = palette.detach().cpu()
        self.on_new_class = on_new_class
        self.control = ViewerControl()
        self._pointer_taken = False
        # the viewer installs elements in attribute-name order: the letters give the panel's order
        self.a_paint = ViewerDropdown("Paint", OFF, [OFF, BRUSH, BOX], cb_hook=lambda element: self.set_mode(
            element.value), hint="Click (brush) or drag (box) on the render to label it with the class below; off "
                                 "to move the camera")
        entries = self.entries()
        self.b_class = ViewerDropdown("Class", entries[0], entries, cb_hook=lambda element: self._show_colour(),
                                      hint="The class painted")
        self.c_colour = ViewerRGB("Class colour", self.colour(0), disabled=True, hint="Its colour in the semantics")
        self.d_brush = ViewerSlider("Brush radius (px)", 3, *BRUSH_RADII, 1,
                                    hint="Radius of a click's disc, in pixels of an image as tall as the training "
                                         "images")
        self.e_new_class = ViewerText("New class", "", hint="Name of a class to add")
        self.f_add_class = ViewerButton("Add class", cb_hook=lambda _: self.add_class(self.e_new_class.value))
        self.g_undo = ViewerButton("Undo last stroke", cb_hook=lambda _: self.undo())
        self.h_status = ViewerText("Strokes", self.summary(), disabled=True, hint="Saved in " + str(store.path))
        self.questions = Questions(store.path.parent.parent)
        self.question: Optional[Question] = None
        self._marker = None
        # (the next pixel `ssnerf-label --suggest-clicks` asks about, marked, with the model's guess picked in Class)
        self.i_ask = ViewerButton("Next suggested click", cb_hook=lambda _: self._reported(self.ask))
        self.j_answer = ViewerButton("Answer with the class picked", cb_hook=lambda _: self._reported(self.answer))
        self.k_skip = ViewerButton("Skip this click", cb_hook=lambda _: self._reported(self.skip))

    def entries(self) -> List[str]:
        return [f"{index}: {name}" for index, name in enumerate(self.class_names)] or [NO_CLASS]

    def colour(self, class_id: int) -> tuple:
        if not 0 <= class_id < len(self.palette):
            return (0, 0, 0)
        return tuple(int(round(float(value) * 255)) for value in self.palette[class_id])

    @property
    def class_id(self) -> Optional[int]:
        """The class picked (None while there is none, or when a client sent a value that is not in the list)."""
        entries = self.entries()
        return entries.index(self.b_class.value) if self.b_class.value in entries and self.class_names else None

    def refusal(self, *positions: Sequence[float], radius: Optional[float] = None) -> Optional[str]:
        """Why a client's stroke must not be written (checked before anything is): no class picked or one not in
        the list, a position outside the image, a brush outside the slider's range; None when it may be."""
        if not self.class_names:
            return "Add a class first (New class, then Add class)."
        if self.class_id is None:
            return f"Not saved: class {str(self.b_class.value)[:MAX_CLASS_NAME]!r} is not in the list; pick one."
        if outside_image(*positions):
            return "Not saved: the stroke is outside the image."
        if radius is not None and not BRUSH_RADII[0] <= radius <= BRUSH_RADII[1]:
            return f"Not saved: brush radius {radius:g} is outside {BRUSH_RADII[0]}..{BRUSH_RADII[1]} px."
        return None

    def summary(self) -> str:
        count, rays = len(self.store.strokes), self.store.num_rays()
        where = "training mixes them into every batch" if self.training_run else "the next ns-train on this data " \
                                                                                  "trains them"
        return f"{count} stroke{'' if count == 1 else 's'}, {rays} rays: {where}"

    def _say(self, text: str) -> None:
        self.h_status.value = text

    def _show_colour(self) -> None:
        self.c_colour.value = self.colour(self.class_id if self.class_id is not None else -1)

    def set_mode(self, mode: str) -> None:
        """Route the viewer's pointer to painting (a click's disc, a drag's box) or give it back to navigation."""
        server = getattr(self.control, "viser_server", None)
        if server is None:  # no viewer (tests drive `paint_disc` / `paint_box` directly)
            return
        if self._pointer_taken:  # (viser warns when asked to remove a callback it does not have)
            self.control.unregister_pointer_cb()
            self._pointer_taken = False
        if mode == BRUSH:
            self.control.register_pointer_cb("click", self._on_click)
        elif mode == BOX:
            self.control.register_pointer_cb("rect-select", self._on_box)
        self._pointer_taken = mode in (BRUSH, BOX)

    def viewer_camera(self) -> Optional[Cameras]:
        """The browser's camera, as tall as the training images (its width from the browser's aspect)."""
        return self.control.get_camera(self.image_height, None)  # type: ignore[arg-type]

    def _on_click(self, click: ViewerClick) -> None:
        camera = self.viewer_camera()
        if camera is not None:
            self.paint_disc(camera, click.screen_pos, float(self.d_brush.value))

    def _on_box(self, box: ViewerRectSelect) -> None:
        camera = self.viewer_camera()
        if camera is not None:
            self.paint_box(camera, box.min_bounds, box.max_bounds)

    def paint_disc(self, camera: Cameras, screen_position: Sequence[float], radius: float) -> Optional[Stroke]:
        """Paint the disc around a point of `camera`'s image (fractions of its width and height)."""
        refused = self.refusal(screen_position, radius=float(radius))
        if refused:
            self._say(refused)
            return None
        width, height = int(camera.width), int(camera.height)
        centre = (screen_position[0] * width, screen_position[1] * height)
        return self.paint(camera, disc_pixels(centre, radius, width, height))

    def paint_box(self, camera: Cameras, corner_min: Sequence[float], corner_max: Sequence[float]) -> Optional[Stroke]:
        """Paint a box of `camera`'s image (corners as fractions of its width and height)."""
        refused = self.refusal(corner_min, corner_max)
        if refused:
            self._say(refused)
            return None
        pixels = box_pixels(corner_min, corner_max, int(camera.width), int(camera.height))
        return self.paint(camera, pixels) if len(pixels) else None

    def paint(self, camera: Cameras, pixels: np.ndarray) -> Optional[Stroke]:
        """Store one stroke: `pixels` (column, row) of `camera`, in the class picked."""
        class_id = self.class_id
        if class_id is None:
            self._say(self.refusal() or "Pick a class.")
            return None
        stroke = stroke_from_pixels(camera, pixels, self.class_names[class_id], self.frame)
        try:
            self.store.add(stroke)
        except OSError as err:  # (a read-only dataset: say so in the panel, the viewer goes on)
            self._say(f"Not saved: {self.store.path} cannot be written ({err.strerror}).")
            return None
        self._say(self.summary())
        return stroke

    def _reported(self, action: Callable[[], object]) -> None:
        """Run a button's action; an error is said in the panel and logged (viser drops a callback's exception)."""
        try:
            action()
        except Exception as err:  # noqa: BLE001 (the panel must say what went wrong, whatever it was)
            CONSOLE.print_exception()
            self._say(f"Failed: {type(err).__name__}: {err}")

    def ask(self) -> Optional[Question]:
        """Open the next unanswered suggested click: its marker, its guess picked, what it asks in the status."""
        try:
            self.question = self.questions.next()
            counts = self.questions.counts()
        except DatasetInputError as err:
            self.question = None
            self._say(str(err))
            return None
        question = self.question
        if question is None:
            self._say(f"No suggested click left ({counts['answered']} answered, {counts['skipped']} skipped).")
            self._show_marker(None)
            return None
        if question.guess in self.class_names:
            self.b_class.value = self.entries()[self.class_names.index(question.guess)]
            self._show_colour()
        self._show_marker(question.point)
        certainty = "" if question.uncertainty is None else f", uncertainty {question.uncertainty:.2f}"
        self._say(f"Click {counts['answered'] + counts['skipped'] + 1} of {counts['total']}: {question.file_path} at "
                  f"({question.x}, {question.y}), marked; the model guesses {question.guess!r}{certainty}. Pick its "
                  "class and Answer, or Skip.")
        return question

    def answer(self) -> Optional[Stroke]:
        """Save the open question's answer (the class picked) as a stroke and in the suggestion file; ask the next."""
        question = self.question
        if question is None:
            self._say("No open question: press Next suggested click.")
            return None
        refused = self.refusal()
        if refused:
            self._say(refused)
            return None
        class_name = self.class_names[self.class_id]  # type: ignore[index]
        try:
            stroke = self.questions.stroke(question, class_name)
            self.store.add(stroke)
            self.questions.mark(question, class_name)
        except DatasetInputError as err:
            self._say(str(err))
            return None
        except OSError as err:
            self._say(f"Not saved: {err.filename or self.store.path} cannot be written ({err.strerror}).")
            return None
        self.question = None
        self.ask()
        return stroke

    def skip(self) -> None:
        """Mark the open question skipped and ask the next."""
        if self.question is None:
            self._say("No open question: press Next suggested click.")
            return
        try:
            self.questions.mark(self.question, None)
        except (DatasetInputError, OSError) as err:
            self._say(str(err))
            return
        self.question = None
        self.ask()

    def _show_marker(self, point: Optional[np.ndarray]) -> None:
        """Mark the surface point asked about (transforms file's frame) in the 3D view, or remove the marker."""
        server = getattr(self.control, "viser_server", None)
        if self._marker is not None:
            self._marker.remove()
            self._marker = None
        if server is None or point is None:
            return
        position = self.frame.to_run(point[None])[0] * VISER_SCALE
        self._marker = server.scene.add_icosphere(MARKER, radius=0.06, color=(255, 0, 255),
                                                  position=tuple(float(v) for v in position))

    def undo(self) -> Optional[Stroke]:
        stroke = self.store.undo()
        self._say(self.summary() if stroke is not None else "No stroke to undo.")
        return stroke

    def add_class(self, name: str) -> bool:
        """Add a class (recorded in the strokes file) and pick it; False, with the reason shown, when it cannot be."""
        name = str(name).strip()
        if not name:
            self._say("Type the new class's name first.")
            return False
        if len(name) > MAX_CLASS_NAME or not name.isprintable():
            self._say(f"Not added: a class name is at most {MAX_CLASS_NAME} printable characters.")
            return False
        if name not in self.class_names:
            if len(self.class_names) >= self.num_slots:
                self._say(f"No free class slot ({self.num_slots} in this model): '{name}' was not added. Declare "
                          "it with ssnerf-label --semantic-classes, or train with more --pipeline.model.spare-classes.")
                return False
            self.store.add_class(name)
            self.class_names.append(name)
            self.b_class.set_options(self.entries())
            self.on_new_class(list(self.class_names))
        self.b_class.value = self.entries()[self.class_names.index(name)]
        self._show_colour()
        self._say(f"Class {self.class_names.index(name)}: {name}. " + self.summary())
        return True


def add_label_panel(model: nn.Module, store: StrokeStore, frame: WorldFrame, image_height: int, training: bool) -> None:
    """Put the Label panel on a class-rendering model (`semantic_labelling`); new classes join its `class_names`."""
    panel = model.semantic_classes

    def new_class(names: List[str]) -> None:
        model.class_names = names
        panel.set_classes(names)

    model.semantic_labelling = LabelPanel(store, frame, model.class_names, model.num_classes, model.palette,
                                          image_height, training, on_new_class=new_class)
