"""Training the TSAC-OCF policy and its deviation verifier."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tsac_bench.cli.app import app, console, user_errors
from tsac_bench.errors import TsacBenchError


@app.command()
@user_errors
def train(
    out: Annotated[Path, typer.Option(help="output folder: checkpoint.pt, policy.pt, "
                                      "curve.json, curve.png")],
    device: Annotated[str, typer.Option(help="auto, cpu or cuda")] = "auto",
    steps: Annotated[int | None, typer.Option(min=1, help="environment steps (decisions) "
                                              "in all; default the shipped policy's")] = None,
    seed: Annotated[int, typer.Option()] = 0,
    resume: Annotated[Path | None, typer.Option(help="a checkpoint.pt to continue from")]
    = None,
    threads: Annotated[int, typer.Option(min=1, help="torch CPU threads")] = 1,
    label_workers: Annotated[int, typer.Option(
        min=1, help="processes that run the rollout labels (the same run, faster on as many "
        "cores); may differ on --resume")] = 1,
    stop_after: Annotated[float | None, typer.Option(
        min=1, help="seconds: end this call at the next episode's end, with a checkpoint to "
        "--resume from")] = None,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", metavar="FIELD=VALUE", help="a scalar field of the training configuration "
        "(TrainConfig), repeatable, e.g. --set rollouts=4 --set replan_share=0; not with "
        "--resume, which keeps the checkpoint's configuration")] = None,
) -> None:
    """Train the TSAC-OCF task-selection policy; the defaults are the shipped policy's
    recipe (docs/tsac.md)."""
    from tsac_bench.planning.settings import config_from_settings, parse_setting_pairs

    if device not in ("auto", "cpu", "cuda"):
        raise TsacBenchError(f"--device: expected auto, cpu or cuda, got {device!r}")
    settings = parse_setting_pairs(setting or [], "--set")
    if settings and resume is not None:
        raise TsacBenchError("--set: not with --resume (a resumed run keeps the configuration "
                             "in its checkpoint)")
    import torch
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from tsac_bench.solvers.tsac.training import TrainConfig, resolve_device
    from tsac_bench.solvers.tsac.training import train as run_training

    torch.set_num_threads(threads)
    if resume is not None and not resume.is_file():
        raise TsacBenchError(f"--resume: {resume} is not a file")
    try:
        resolve_device(device)
    except ValueError as exc:
        raise TsacBenchError(str(exc)) from None
    if steps is None:
        steps = (torch.load(resume, map_location="cpu", weights_only=False)["config"]["steps"]
                 if resume is not None else TrainConfig().steps)
    config = config_from_settings(TrainConfig, settings, "--set", steps=steps, seed=seed)
    columns = (TextColumn("[bold]train"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
    with Progress(*columns, console=console) as progress:
        bar = progress.add_task("train", total=steps, info="")

        def on_step(step: int, stats: dict[str, float]) -> None:
            info = " ".join(f"{k}={stats[k]:.3g}" for k in ("critic_loss", "entropy",
                                                             "eval_ratio_hocf") if k in stats)
            progress.update(bar, completed=step, info=info)

        summary = run_training(out, config, device=device, resume=resume, on_step=on_step,
                               stop_after=stop_after, label_workers=label_workers)
    console.print(f"trained {summary['steps']} steps ({summary['episode_count']} episodes) in "
                  f"{summary['seconds']:.0f} s on {summary['device']}; policy: "
                  f"{out / 'policy.pt'}")



@app.command("train-verifier")
@user_errors
def train_verifier_command(
    out: Annotated[Path, typer.Option(help="output folder: policy.pt (the policy with its "
                                      "verifier), labels.pt, verifier.json")],
    policy: Annotated[Path | None, typer.Option(
        help="the policy file whose critics' deviations are verified; default the shipped "
        "one")] = None,
    workers: Annotated[int, typer.Option(min=1, help="processes that label the instances "
                                         "(the same labels with any number)")] = 1,
    labels: Annotated[Path | None, typer.Option(
        help="the labels.pt of an earlier call (same policy and labelling settings): fit "
        "only")] = None,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", metavar="FIELD=VALUE", help="a field of VerifierConfig, repeatable, e.g. "
        "--set epochs=10")] = None,
) -> None:
    """Train the deviation verifier of tsac-ocf's margin rule (docs/tsac.md)."""
    from tsac_bench.planning.settings import config_from_settings, parse_setting_pairs
    from tsac_bench.solvers.tsac.policy import margin_problem, policy_at
    from tsac_bench.solvers.tsac.verify import VerifierConfig, train_verifier

    config = config_from_settings(VerifierConfig, parse_setting_pairs(setting or [], "--set"),
                                  "--set")
    if policy is not None and not policy.is_file():
        raise TsacBenchError(f"--policy: {policy} is not a file")
    # An unreadable policy file is a PolicyFileError: one line naming the file.
    source = str(policy) if policy else None
    problem = margin_problem(policy_at(source))
    if problem is not None:
        raise TsacBenchError(f"--policy: {policy or 'the shipped policy'}: {problem}")
    if labels is not None and not labels.is_file():
        raise TsacBenchError(f"--labels: {labels} is not a file")
    summary = train_verifier(out, source, config, workers, labels)
    console.print(f"{summary['labels']} labels ({summary['seconds_labelling']:.0f} s), fitted "
                  f"in {summary['seconds_fit']:.0f} s; policy: {out / 'policy.pt'}")

