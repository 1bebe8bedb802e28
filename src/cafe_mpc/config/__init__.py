"""Run configurations: YAML files a user can read and edit, validated at the boundary.

``run``: the schema of a run config (``RunConfig`` and its sections) and its presets (``load_config``);
``loading``: what run configs share with trajectory-optimisation tasks (strict models, ``--set`` overrides
by dotted key, one-line validation errors, presets).
"""

from cafe_mpc.config.estimation import KinematicKFSettings
from cafe_mpc.config.loading import ConfigError, StrictModel, format_validation_error, parse_override
from cafe_mpc.config.run import (
    DEFAULT_FRICTION,
    PAPER_BUDGET_FRACTION,
    PRESET_DIR,
    CostsConfig,
    EncoderSpec,
    FallConfig,
    GaitConfig,
    ImuSpec,
    MpcConfig,
    MpcSettings,
    OutputConfig,
    PDConfig,
    PlantConfig,
    PushConfig,
    ReferenceConfig,
    ReferenceSegmentConfig,
    RunConfig,
    SceneConfig,
    SensorNoise,
    SensorsConfig,
    SimulationConfig,
    TemplateConfig,
    TerrainConfig,
    TrajectoryCostsConfig,
    VelocityCommand,
    VWBCConfig,
    available_presets,
    load_config,
)
from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights

__all__ = [
    "DEFAULT_FRICTION",
    "PAPER_BUDGET_FRACTION",
    "PRESET_DIR",
    "ConfigError",
    "CostsConfig",
    "EncoderSpec",
    "FallConfig",
    "GaitConfig",
    "ImuSpec",
    "KinematicKFSettings",
    "MpcConfig",
    "MpcSettings",
    "OutputConfig",
    "PDConfig",
    "PlantConfig",
    "PushConfig",
    "ReferenceConfig",
    "ReferenceSegmentConfig",
    "RunConfig",
    "SRBWeights",
    "SceneConfig",
    "SensorNoise",
    "SensorsConfig",
    "SimulationConfig",
    "StrictModel",
    "TemplateConfig",
    "TerrainConfig",
    "TrajectoryCostsConfig",
    "VWBCConfig",
    "VelocityCommand",
    "WholeBodyWeights",
    "available_presets",
    "format_validation_error",
    "load_config",
    "parse_override",
]
