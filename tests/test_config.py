from pathlib import Path

import pytest

from sfb_video.config import Config, config_to_dict, load_config
from sfb_video.errors import ConfigError


def test_default_preset_matches_the_paper() -> None:
    cfg = load_config("default")
    assert cfg.render.sigma_inv == 7000.0
    assert cfg.render.time_steps == 8


def test_fast_preset_overrides_only_what_it_names() -> None:
    cfg = load_config("fast")
    assert cfg.render.time_steps == 4
    assert cfg.render.sigma_inv == Config().render.sigma_inv


def test_dotted_overrides_are_typed() -> None:
    cfg = load_config("default", ["render.sigma_inv=3000", "demo.size_px=[10, 20]"])
    assert cfg.render.sigma_inv == 3000.0
    assert cfg.demo.size_px == (10.0, 20.0)
    assert load_config("default", ["fit.prototypes=[torus]"]).fit.prototypes == ("torus",)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("render.sigmainv=3", "unknown config key render.sigmainv"),
        ("render.time_steps=2.5", "render.time_steps must be int"),
        ("demo.size_px=[1, 2, 3]", "list of 2 values"),
        ("render", "must look like"),
        ("fit.prototypes=[]", "non-empty list"),
        ("fit.difference_fade=0", "fit.difference_fade must be > 0, got 0.0"),
        ("fit.iterations=-5", "fit.iterations must be >= 1, got -5"),
        ("video.exposure_fraction=1.5", "video.exposure_fraction must be > 0 and <= 1, got 1.5"),
        ("fit.w_image=-1", "fit.w_image must be >= 0"),
        ("fit.size_range=[0.5, 0.1]", "low < high"),
        (
            "fit.prototypes=[cube]",
            "fit.prototypes must be one of sphere, sphere_large, torus, capsule, box, disc; got 'cube'",
        ),
        ("render.sigma_inv=.nan", "render.sigma_inv must be a finite number"),
    ],
)
def test_bad_overrides_name_the_problem(override: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config("default", [override])


def test_missing_and_malformed_presets(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no config preset 'no_such_preset'; the presets are default, fast"):
        load_config("no_such_preset")
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("render: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_resolved_config_round_trips_through_yaml(tmp_path: Path) -> None:
    import yaml

    cfg = load_config("fast", ["render.sigma_inv=123"])
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config_to_dict(cfg)))
    assert load_config(path) == cfg


def test_every_loss_weight_zero_is_a_config_error_not_a_traceback() -> None:
    zero = [f"fit.{w}=0" for w in ("w_image", "w_silhouette", "w_difference", "w_texture", "w_laplacian")]
    with pytest.raises(ConfigError, match=r"every loss weight .* is 0"):
        load_config("fast", zero)
    load_config("fast", zero[1:])  # L_I alone is a fit
