"""``datt export``: the policy for another runtime (C99 source, TorchScript, ONNX)."""

from __future__ import annotations

from pathlib import Path

import torch
from omegaconf import DictConfig

from datt.errors import ConfigError
from datt.export import ObservePolicyModule, export_spec, write_c
from datt.export.app import write_app
from datt.paths import original_cwd
from datt.tasks.common import console, hydra_run_dir, set_threads
from datt.tasks.validation import validate_config


def check_out_dir(out: Path) -> None:
    """``out_dir`` is (or can be made as) a directory: one line before anything is built."""
    base = out
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise ConfigError(f"out_dir: {base} is a file, not a directory; give a directory (it is made if missing)")


def run_export(cfg: DictConfig, run_dir: Path | None = None) -> list[Path]:
    validate_config("export", cfg)
    fmt, prefix = str(cfg.format), str(cfg.prefix)
    set_threads(cfg.threads)
    out = Path(str(cfg.out_dir)) if cfg.out_dir else (run_dir or hydra_run_dir())
    if not out.is_absolute():
        out = original_cwd() / out
    check_out_dir(out)
    spec, controller, merged = export_spec(cfg)
    if fmt == "c":
        paths = list(write_c(spec, out, prefix))
    elif fmt == "app":
        paths = write_app(spec, out)
    else:
        module = ObservePolicyModule(controller, spec.horizon, merged.env.obs).eval()
        example = module.example_inputs()
        path = out / f"{prefix}_policy.{'pt' if fmt == 'torchscript' else 'onnx'}"
        out.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        if fmt == "torchscript":
            with torch.no_grad():
                torch.jit.save(torch.jit.trace(module, example, check_trace=False), str(tmp))
        else:
            export_onnx(module, example, tmp)
        tmp.replace(path)
        paths = [path]
    for path in paths:
        console.print(f"wrote {path}")
    return paths


def export_onnx(module, example, path: Path) -> None:
    try:
        import onnx  # noqa: F401
    except ImportError:
        raise ConfigError('format: onnx needs the onnx package: pip install -e ".[export]"') from None
    names = ["pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_history"]
    with torch.no_grad():
        torch.onnx.export(
            module,
            example,
            str(path),
            input_names=names,
            output_names=["action"],
            dynamic_axes={n: {0: "batch"} for n in [*names, "action"]},
            dynamo=False,
        )
