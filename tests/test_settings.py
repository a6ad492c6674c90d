"""Encoder options are declared once (codec.settings) and every entry point agrees with
that declaration: codec.encode's signature, the meshers' build(), `atm encode`."""

from __future__ import annotations

import dataclasses
import inspect
import typing

import numpy as np
import pytest

import codec
from codec.cli import convert
from codec.cli.main import build_parser
from codec.errors import OptionError
from codec.mesher import builder
from codec.settings import MESHERS, Settings, cli_option_names, mesher_option_names, option_names


def test_every_option_has_a_type_a_default_and_a_doc():
    hints = typing.get_type_hints(Settings)
    for f in dataclasses.fields(Settings):
        assert f.name in hints
        assert f.default is not dataclasses.MISSING
        assert len(f.metadata["doc"]) > 20, f.name


def test_encode_signature_is_the_settings():
    params = inspect.signature(codec.encode).parameters
    keywords = {n: p for n, p in params.items() if p.kind is p.KEYWORD_ONLY}
    assert list(keywords) == list(option_names()) + ["mask"]
    for f in dataclasses.fields(Settings):
        assert keywords[f.name].default == f.default, f.name
        assert keywords[f.name].annotation == f.type, f.name
    assert params["unknown"].kind is inspect.Parameter.VAR_KEYWORD


def test_each_meshers_options_are_its_build_keywords():
    for name in MESHERS:
        params = inspect.signature(builder(name)).parameters
        keywords = [n for n, p in params.items() if p.kind is p.KEYWORD_ONLY]
        assert sorted(keywords) == sorted(mesher_option_names(name)), name


def _encode_parser():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command" or getattr(a, "choices", None) and "encode" in a.choices)
    return sub.choices["encode"]


def test_every_encode_flag_is_an_option_and_forwarded():
    """A flag added to `atm encode` must be an encoder option (then it is forwarded
    by name) or listed as not one: it cannot be silently dropped."""
    encode = _encode_parser()
    dests = {a.dest for a in encode._actions if a.dest != "help"}
    assert dests - set(convert.NOT_ENCODER_OPTIONS) == set(cli_option_names())
    flags = {
        "--band-height": "16", "--mesher": "uniform", "--nodata": "3", "--value-range": ["0", "1"],
        "--precision": "0.01", "--metadata": '{"units": "m"}', "--effort": "2",
    }
    # the size flags exclude each other (points or a bound; quality or max_rms): three runs
    seen = set()
    for size in ({"--points": "100", "--lossless": []}, {"--quality": "50", "--max-error": "4"}, {"--max-rms": "1.5"},
                 {"--max-error": "4", "--residual": []}):
        argv = ["in.png", "out.atm"]
        for flag, value in {**flags, **size}.items():
            argv += [flag] + (value if isinstance(value, list) else [value])
        options = convert.encode_options(encode.parse_args(argv))
        assert options["value_range"] == (0.0, 1.0) and options["metadata"] == {"units": "m"}
        seen |= set(options)
    assert seen == set(cli_option_names())


def test_unknown_options_list_the_valid_ones():
    image = np.zeros((8, 8), np.uint8)
    with pytest.raises(OptionError, match="the options are: " + ", ".join(option_names()) + ", mask$"):
        codec.encode(image, colour=1)
    for call in (
        lambda: codec.StreamEncoder(__import__("io").BytesIO(), 8, 8, colour=1),
        lambda: Settings.from_options(colour=1),
    ):
        with pytest.raises(OptionError, match="unknown encoder option colour; the options are: " + ", ".join(option_names())):
            call()
    with pytest.raises(OptionError, match="build_mesh takes points, mesher and the mesher's options"):
        codec.build_mesh(image, metadata={"a": 1})


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(points=0), "points must be a positive whole number"),
        (dict(points=2.5), "points must be a positive whole number"),
        (dict(quality=101), "quality must be a whole number from 1 to 100"),
        (dict(quality=50, max_rms=1.0), "quality and max_rms both set the size"),
        (dict(max_rms=-1), "max_rms must be a finite number >= 0"),
        (dict(max_error=float("nan")), "max_error must be a finite number >= 0"),
        (dict(value_step=0), "value_step must be 'auto' or a whole number 1..65535"),
        (dict(mesher="nope"), "unknown mesher 'nope'; choose one of adaptive, uniform"),
        (dict(mesher="uniform", tiles=(2, 2)), "mesher 'uniform' has no option tiles; its options are: values"),
        (dict(value_range=5), "value_range must be a pair"),
        (dict(metadata=[1]), "metadata must be a dict"),
        (dict(nodata="x"), "nodata must be a number"),
    ],
)
def test_bad_options_are_refused_by_name(options, message):
    with pytest.raises(OptionError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Settings.from_options(**options)


def test_settings_are_values():
    a = Settings.from_options(points=100, canny=(10, 30))
    assert a == Settings(points=100, canny=(10, 30)) and hash(a) == hash(Settings(points=100, canny=(10, 30)))
    assert a.given() == {"points": 100, "canny": (10, 30)}
    assert a.mesher_options() == {"canny": (10, 30)}
    assert a.replace(points=5).points == 5 and a.points == 100
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.points = 3  # type: ignore[misc]


def test_stream_options_override_the_settings_given():
    import io

    base = Settings(mesher="uniform", points=50)
    enc = codec.StreamEncoder(io.BytesIO(), 20, 10, settings=base, mesher="adaptive")
    assert enc._plan.settings.mesher == "adaptive" and enc._plan.settings.points == 50
