"""The torch side's one device fallback (recon.device.torch_device)."""

import logging

import pytest
import torch

from recon.device import torch_device


def test_cuda_falls_back_to_the_cpu_with_a_notice(monkeypatch, caplog):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with caplog.at_level(logging.WARNING, logger="recon.device"):
        assert torch_device("cuda") == "cpu"
    assert "no CUDA device" in caplog.text


def test_cpu_and_an_available_cuda_are_kept(monkeypatch, caplog):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    with caplog.at_level(logging.WARNING, logger="recon.device"):
        assert torch_device("cuda") == "cuda"
        assert torch_device("cpu") == "cpu"
    assert caplog.text == ""


def test_an_unknown_device_names_the_option():
    with pytest.raises(ValueError, match="--device"):
        torch_device("tpu")
