"""The suite runs on as many workers as the machine has cores (pytest-xdist, ``-n auto`` in pyproject.toml): each
worker then takes one intra-op thread, or the workers' threads would contend for the same cores."""

import os

import torch

if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)
