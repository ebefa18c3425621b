"""Builds an identifier from its configuration name, resolving the models it needs.

Names: `ccf10`, `ccf25` (CCF weights), `channels` (weight-free LUV + gradients), `reid`
(deep re-id embedding only), and a feature set plus `+reid` (e.g. `ccf10+reid`).
"""

from __future__ import annotations

from follow.ccf.channels import ChannelFeatureExtractor
from follow.ccf.features import FeatureExtractor
from follow.ccf.network import CcfExtractor
from follow.ccf.weights import load_ccf_weights
from follow.config import Config, ConfigError, IdentifyConfig
from follow.identify.appearance import AppearanceModel
from follow.identify.identifier import TargetIdentifier
from follow.identify.reid import ReidEmbedder

FEATURE_SETS = ("ccf10", "ccf25", "channels")
REID_MODEL = "person-reidentification-retail-0248"
IDENTIFIERS = ("ccf10", "ccf25", "channels", "reid", "ccf10+reid", "ccf25+reid", "channels+reid")


def parse_identifier(name: str) -> tuple[str | None, bool]:
    """(feature set or None, whether re-id is used) of an identifier name."""
    parts = [p.strip() for p in name.lower().split("+")]
    use_reid = "reid" in parts
    features = [p for p in parts if p != "reid"]
    if len(features) > 1 or (features and features[0] not in FEATURE_SETS) or len(parts) > 2:
        raise ConfigError(f"identifier '{name}' not understood; known: {', '.join(IDENTIFIERS)}")
    if not features and not use_reid:
        raise ConfigError(f"identifier '{name}' names no cue; known: {', '.join(IDENTIFIERS)}")
    return (features[0] if features else None), use_reid


def build_extractor(feature_set: str, config: IdentifyConfig) -> FeatureExtractor:
    """The feature extractor of a feature set; CCF weights come from the model registry."""
    from follow.models import resolve

    crop_size = (config.crop_width_px, config.crop_height_px)
    if feature_set == "channels":
        return ChannelFeatureExtractor(crop_size)
    if feature_set in ("ccf10", "ccf25"):
        weights = load_ccf_weights(resolve(feature_set))
        return CcfExtractor(weights, crop_size, threads=config.feature_threads, name=feature_set)
    raise ConfigError(f"feature set '{feature_set}' unknown; known: {', '.join(FEATURE_SETS)}")


def build_reid(config: IdentifyConfig) -> ReidEmbedder:
    from follow.models import resolve

    return ReidEmbedder(
        resolve(REID_MODEL), threads=config.reid_threads, provider=config.reid_provider
    )


def _section(config: IdentifyConfig | Config) -> IdentifyConfig:
    return config.identify if isinstance(config, Config) else config


def _cues(cfg: IdentifyConfig) -> tuple[FeatureExtractor | None, ReidEmbedder | None]:
    """The feature extractor and re-id network `cfg.identifier` names (None where unused)."""
    feature_set, use_reid = parse_identifier(cfg.identifier)
    extractor = build_extractor(feature_set, cfg) if feature_set else None
    return extractor, build_reid(cfg) if use_reid else None


def build_appearance_model(config: IdentifyConfig | Config) -> AppearanceModel:
    cfg = _section(config)
    return AppearanceModel(cfg, *_cues(cfg))


def build_identifier(config: IdentifyConfig | Config) -> TargetIdentifier:
    """The TargetIdentifier named by `config.identifier` (raises ModelError if a model is
    missing, ConfigError for an unknown name)."""
    cfg = _section(config)
    return TargetIdentifier(cfg, *_cues(cfg))
