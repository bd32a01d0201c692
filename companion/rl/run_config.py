"""What a PPO or fine-tuning run flew: the companion's and the SITL's configuration (the
disturbance level among them) and the numeric environment, written beside its settings.

A PPO result means nothing without the task it was trained on, and ``settings.json`` holds only
the algorithm's options; so ``run_config.json`` keeps the rest, ``results.json`` names the
disturbance level, and a folder is continued only with the configuration it was started with.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from colcommon.numeric_env import append_record
from companion.config import CompanionConfig
from companion.errors import ConfigError

RUN_CONFIG = "run_config.json"


def run_config(cfg: CompanionConfig, config_path: Path | None) -> dict[str, Any]:
    """The configuration as JSON: the companion's tables, the SITL's, and the file they came from."""
    from sitl.config import load_sitl_config

    sitl = load_sitl_config(config_path).model_dump(mode="json")
    if sitl["camera"].get("pad_marker") == "none":  # added later: at its default, older folders still continue
        del sitl["camera"]["pad_marker"]
    return {"config_path": None if config_path is None else str(config_path),
            "companion": cfg.model_dump(mode="json"), "sitl": sitl}


def task_summary(config: dict[str, Any]) -> dict[str, Any]:
    """The few fields a reader of ``results.json`` needs to know which task it was."""
    return {"config_path": config["config_path"], "disturbance_level": config["sitl"]["disturbance"]["level"]}


def record_run_config(out_dir: Path, cfg: CompanionConfig, config_path: Path | None) -> dict[str, Any]:
    """Write ``run_config.json`` for a new folder, or refuse a folder started with another
    configuration (naming what differs); add this start's numeric environment either way."""
    config = run_config(cfg, config_path)
    path = out_dir / RUN_CONFIG
    if path.exists():
        before = json.loads(path.read_text())
        changed = sorted(f"{part}.{key}" for part in ("companion", "sitl")
                         for key in set(before[part]) | set(config[part])
                         if before[part].get(key) != config[part].get(key))
        if changed:
            raise ConfigError(f"{out_dir} was started with another configuration ({', '.join(changed)} differ); "
                              "pass the same --config, or another --out")
    else:
        path.write_text(json.dumps(config, indent=1) + "\n")
    append_record(out_dir, command=sys.argv)
    return config
