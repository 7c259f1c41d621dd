"""``craft``: the runtime's command line (grounding, evaluation, simulation, installs, serving).

This module only assembles the command groups; each command is a thin function in its own module
of this package, over the library (``grounding``, ``kb``, ``evaluation``, ``sim``, ``serve``).
The command modules import nothing from here, so there is no registration cycle. Heavy imports
(torch, matplotlib, encoders) happen inside command bodies so ``craft --help`` stays fast, and the
runtime CLI never imports the compiler, httpx or rdflib.

Exit codes (``common``): 0 ok; 2 bad input or usage (files, boxes, unknown verb, bundle refused);
1 a check failed (verification commands).
"""

from __future__ import annotations

import os

import typer

from ...signals import exit_through_python_on_sigterm
from . import (
    eval_compare,
    eval_imagenet,
    eval_kb,
    eval_open_world,
    eval_pickability,
    eval_recognition,
    eval_sim,
    eval_static,
    eval_zhu,
    ground,
    install,
    perceive,
    robustness,
    serve,
    sim,
)

app = typer.Typer(help="CRAFT-E runtime: ground verbs in scenes, evaluate, simulate, install KBs.",
                  no_args_is_help=True, add_completion=False)
eval_app = typer.Typer(help="Benchmarks: JSON + Markdown tables.", no_args_is_help=True)
sim_app = typer.Typer(help="The simulated CR3 testbed.", no_args_is_help=True)
robustness_app = typer.Typer(help="Robustness of the method to perceptual noise.", no_args_is_help=True)
app.add_typer(eval_app, name="eval")
app.add_typer(sim_app, name="sim")
eval_app.add_typer(robustness_app, name="robustness")

app.command("ground")(ground.ground)
app.command("perceive")(perceive.perceive)
app.command("install")(install.install_cmd)
app.command("rollback")(install.rollback_cmd)
app.command("installed")(install.installed_cmd)
app.command("serve")(serve.serve_cmd)
eval_app.command("imagenet")(eval_imagenet.eval_imagenet)
eval_app.command("sim")(eval_sim.eval_sim)
eval_app.command("static")(eval_static.eval_static)
eval_app.command("zhu")(eval_zhu.eval_zhu)
eval_app.command("kb")(eval_kb.eval_kb)
eval_app.command("open-world")(eval_open_world.eval_open_world)
eval_app.command("recognition")(eval_recognition.eval_recognition)
eval_app.command("pickability")(eval_pickability.eval_pickability)
eval_app.command("compare")(eval_compare.eval_compare)
robustness_app.command("imagenet")(robustness.robustness_imagenet)
sim_app.command("demo")(sim.demo)
sim_app.command("collision-meshes")(sim.collision_meshes)


def main() -> None:
    """The ``craft`` console script: process-wide settings first, then the app.

    ``ground`` multiplies tiny matrices ([10, 384] x [384, 400]); multi-threaded OpenBLAS turns
    that into 1-20 ms of thread hand-offs on a busy 2-core host (0.3 ms single-threaded), so one
    thread unless the user says otherwise. The runtime never reaches the network: the Hugging
    Face libraries are told so. Set here, when the program starts, never at import time.
    """
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    exit_through_python_on_sigterm()  # `craft serve` replaces it with uvicorn's graceful shutdown
    app(prog_name="craft")
