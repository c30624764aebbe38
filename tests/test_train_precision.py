"""`train --precision bf16`: the step runs under bf16 autocast (so its result differs from float32's), the weights
stay float32 and finite, and the setting is saved with the run."""
from __future__ import annotations

import json

import pytest
import torch
from click.testing import CliRunner
from test_train import cli_args, dataset, tiny_config  # noqa: F401  (fixtures)

from insertnerf_cli.cli.main import cli


def _weights(run) -> dict[str, torch.Tensor]:
    return torch.load(run / "checkpoints" / "last.pt", weights_only=True)["model"]


@pytest.mark.slow
def test_bf16_steps_are_autocast_and_keep_float32_weights(dataset, tiny_config, tmp_path):  # noqa: F811
    runs = {}
    for precision in ("fp32", "bf16"):
        run = tmp_path / precision
        result = CliRunner().invoke(cli, cli_args(dataset, run, tiny_config, "--steps", "2", "--precision", precision))
        assert result.exit_code == 0, result.output
        assert json.loads((run / "checkpoints" / "config.json").read_text())["train"]["precision"] == precision
        runs[precision] = _weights(run)
    floats = [n for n, t in runs["bf16"].items() if t.is_floating_point()]
    assert all(runs["bf16"][n].dtype == torch.float32 and torch.isfinite(runs["bf16"][n]).all() for n in floats)
    assert any(not torch.equal(runs["bf16"][n], runs["fp32"][n]) for n in floats)  # autocast was in effect


@pytest.mark.slow
def test_an_unknown_precision_is_refused(dataset, tiny_config, tmp_path):  # noqa: F811
    result = CliRunner().invoke(cli, cli_args(dataset, tmp_path / "run", tiny_config, "--precision", "fp16"))
    assert result.exit_code == 2 and "fp16" in result.output and not (tmp_path / "run").exists()


@pytest.mark.slow
def test_a_compiler_failure_under_compile_is_one_line(dataset, tiny_config, tmp_path, monkeypatch):  # noqa: F811
    """torch 2.13's inductor failed on this model with dynamic shapes; any such failure must end as one line."""
    import torch._dynamo.exc as dynamo_exc

    def failing_compile(module, **_):
        def run(*args, **kwargs):
            raise dynamo_exc.InternalTorchDynamoError("inductor could not lower\nAttributeError: no python_mod")
        return run

    monkeypatch.setattr(torch, "compile", failing_compile)
    result = CliRunner().invoke(cli, cli_args(dataset, tmp_path / "run", tiny_config, "--steps", "2", "--compile"))
    assert result.exit_code == 1 and "torch.compile failed at step 1" in result.output, result.output
    assert "no python_mod" in result.output and "Traceback" not in result.output


@pytest.mark.slow
def test_compile_compiles_the_aggregation_with_the_same_result(dataset, tiny_config, tmp_path, monkeypatch):  # noqa: F811
    """--compile compiles the per-scale aggregators (dynamic shapes: training and validation ray counts differ);
    two steps give the eager run's weights within float tolerance, under the same names."""
    compiled = []
    original = torch.nn.Module.compile

    def recording_compile(module, *args, **kwargs):
        compiled.append((type(module).__name__, kwargs.get("dynamic")))
        original(module, *args, **kwargs)

    monkeypatch.setattr(torch.nn.Module, "compile", recording_compile)
    runs = {}
    for flag in ("--no-compile", "--compile"):
        run = tmp_path / flag.strip("-")
        result = CliRunner().invoke(cli, cli_args(dataset, run, tiny_config, "--steps", "2", flag))
        assert result.exit_code == 0, result.output
        runs[flag] = _weights(run)
    assert compiled == [("ScaleAggregator", True)] * 3
    assert runs["--compile"].keys() == runs["--no-compile"].keys()
    for name, eager in runs["--no-compile"].items():
        # Compiled kernels sum in another order; Adam's first steps move a weight by about the learning rate
        # whatever its gradient's size, so rounding differences reach a few 1e-5 (seen: 2.9e-5 on this machine).
        torch.testing.assert_close(runs["--compile"][name], eager, rtol=1e-4, atol=1e-4, msg=name)
