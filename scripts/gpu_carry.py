"""Prepare a folder to carry to a lent GPU machine that has no package registry (run here, where pip answers).

The lent machine's image (`/work/.library/device/KINDS.md`) holds Python 3.12 with torch, numpy, scipy, OpenCV,
matplotlib, pytest and most of what nerfstudio imports, but not nerfstudio itself nor a few of its dependencies, and
nothing can be downloaded there. This script downloads, without their dependencies, the wheels of exactly those
missing distributions at the versions installed in this checkout's environment (the ones CI tests), built for the
image's Python, and generates the GPU check's 640x480 scene (about 30 s less of device time). On the machine,
`scripts/gpu_check.sh` installs the wheels (`--no-index --no-deps`) and this checkout (editable) before the check.

    .venv/bin/python scripts/gpu_carry.py
    # then, on the device with carry [".gpucarry"]: scripts/gpu_check.sh --output .gpucarry/gpu_check
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import List

import tyro

MISSING_ON_THE_IMAGE = (
    "nerfstudio", "nerfacc", "gsplat", "tyro", "docstring_parser", "typeguard", "typing_extensions", "jaxtyping",
    "viser", "websockets", "msgspec", "appdirs", "defusedxml", "dill", "multiprocess", "pathos", "ppft", "fpsample",
    "pyquaternion", "PySocks", "pytorch-msssim", "rawpy", "splines", "tensorly", "torch_fidelity",
)
"""Distributions a training and the GPU check import that the image lacks (found by tracing `sys.modules` through a
tiny `ssnerf-lite` and `ssnerf` run and its `ns-eval`, then subtracting the image's package list). typing_extensions
and jaxtyping are there, but older than tyro needs."""

IMAGE_HAS = frozenset("""
absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build certifi
charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings cuda-core cuda-pathfinder
cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils execnet filelock flatbuffers flax
fonttools formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet httpcore httpx huggingface-hub humanize
hypothesis idna imageio iniconfig interface-meta jax jax-cuda13-pjrt jax-cuda13-plugin jaxlib jaxtyping jinja2
joblib kiwisolver lazy-loader lightning lightning-utilities linear-operator lineax llvmlite lxml markdown
markdown-it-py markupsafe matplotlib mdurl meson ml-dtypes mpi4py mpmath msgpack multidict multipledispatch
mypy-extensions nanobind narwhals networkx ninja numba numba-cuda numpy numpyro nvidia-cublas nvidia-cuda-cupti
nvidia-cuda-nvrtc nvidia-cuda-runtime nvidia-cudnn-cu13 nvidia-cufft nvidia-cufile nvidia-curand nvidia-cusolver
nvidia-cusparse nvidia-cusparselt-cu13 nvidia-ml-py nvidia-nccl-cu13 nvidia-nvjitlink nvidia-nvshmem-cu13
nvidia-nvtx onnx onnx-ir onnxruntime onnxscript opencv-python-headless optax opt-einsum opt-einsum-fx optimistix
orbax-checkpoint packaging pandas pathspec patsy peft pillow pip pluggy portalocker prometheus-client propcache
protobuf psutil pyarrow pybind11 py-cpuinfo pygments pyparsing pyproject-hooks pyre-extensions pytest
pytest-benchmark pytest-cov pytest-mock pytest-timeout pytest-xdist python-dateutil pytorch-lightning pyyaml regex
requests rich sacrebleu safetensors scikit-build-core scikit-image scikit-learn scipy seaborn sentencepiece
sentence-transformers setuptools shellingham simplejson six sortedcontainers statsmodels sympy tabulate tensorboard
tensorboard-data-server tensorstore threadpoolctl tifffile tiktoken timm tokenizers toolz torch torchaudio
torchdiffeq torch-geometric torchmetrics torchvision tqdm transformers treescope triton typer typing-extensions
typing-inspect urllib3 uvloop wadler-lindig werkzeug wheel wrapt xarray xxhash yarl zipp
""".split())
"""The distributions of the image (`KINDS.md`, as read on 2026-11-17), by their normalized names."""

IMAGE_PYTHON = "3.12"
PLATFORMS = ("manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux_2_28_x86_64", "manylinux_2_34_x86_64", "any")


@dataclass
class GpuCarryConfig:
    """Download the wheels a lent GPU machine lacks and generate the GPU check's scene, into one folder to carry."""

    output: Path = Path(".gpucarry")
    """The folder to name in `carry` (git-ignored by `.git/info/exclude`: this script adds it)."""
    scene: bool = True
    """Also generate the GPU check's 640x480 scene (`OUTPUT/gpu_check/scene`, which `gpu_check.sh --output
    OUTPUT/gpu_check` reuses)."""
    dry_run: bool = False
    """Print the pip commands and do nothing."""


def pins() -> List[str]:
    """`name==version` for each missing distribution, at the version installed here (the fallback: the newest one)."""
    result = []
    for name in MISSING_ON_THE_IMAGE:
        try:
            result.append(f"{name}=={version(name)}")
        except PackageNotFoundError:
            result.append(name)
    return result


def download_command(pin: str, wheels: Path) -> List[str]:
    platforms = [argument for platform in PLATFORMS for argument in ("--platform", platform)]
    return [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--dest", str(wheels),
            "--python-version", IMAGE_PYTHON, "--implementation", "cp", "--abi", "cp312", "--abi", "abi3",
            "--abi", "none", *platforms, pin]


def main(config: GpuCarryConfig) -> None:
    wheels = config.output / "wheels"
    commands = [download_command(pin, wheels) for pin in pins()]
    if config.dry_run:
        print("\n".join(" ".join(command) for command in commands))
        return
    wheels.mkdir(parents=True, exist_ok=True)
    exclude = Path(subprocess.run(["git", "rev-parse", "--git-path", "info/exclude"], capture_output=True, text=True,
                                  check=True).stdout.strip())
    line = f"/{config.output.as_posix().strip('/')}/"
    if line not in (exclude.read_text().splitlines() if exclude.is_file() else []):
        exclude.parent.mkdir(parents=True, exist_ok=True)
        with exclude.open("a") as handle:
            handle.write(line + "\n")
    for command in commands:  # one at a time: a pin without a wheel for the image falls back to the newest that has
        if subprocess.run(command).returncode != 0:
            name = command[-1].split("==")[0]
            print(f"gpu_carry: no wheel of {command[-1]} for Python {IMAGE_PYTHON}; taking the newest {name} with one")
            subprocess.run([*command[:-1], name], check=True)
    if config.scene and not (config.output / "gpu_check" / "scene" / "transforms.json").is_file():
        from ssnerf_method.scene.make_scene import MakeSceneConfig, make_scene

        make_scene(MakeSceneConfig(output_dir=config.output / "gpu_check" / "scene", width=640, height=480,
                                   num_frames=30))
    size = sum(path.stat().st_size for path in config.output.rglob("*") if path.is_file()) / 2**20
    print(f"gpu_carry: {config.output} holds {len(list(wheels.glob('*.whl')))} wheels, {size:.0f} MiB in all (the "
          "carry limit is 64 MiB with the working tree)")


if __name__ == "__main__":
    main(tyro.cli(GpuCarryConfig))
