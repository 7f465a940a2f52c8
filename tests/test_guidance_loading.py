"""Loading the diffusion models from hub-like folders, clear errors for missing weights, and
species LoRA files in the layouts found in the wild."""

import time

import pytest
import torch
from safetensors.torch import save_file

from plantdreamer.cameras import orbit
from plantdreamer.errors import InputError, ModelNotFoundError
from plantdreamer.guidance import models
from plantdreamer.guidance.lora_weights import count_lora_layers, load_lora
from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
from plantdreamer.guidance.tiny import save_tiny_models, tiny_models

RES = 64


@pytest.fixture(scope="module")
def hub_folders(tmp_path_factory):
    return save_tiny_models(tmp_path_factory.mktemp("models"), seed=3)


def sds_loss(guidance):
    images = torch.rand(1, 32, 32, 3, generator=torch.Generator().manual_seed(0))
    images.requires_grad_(True)
    depth = torch.rand(1, 1, RES, RES, generator=torch.Generator().manual_seed(1))
    out = guidance(images, depth, [orbit(4.0, 15.0, 0.0, 60.0, 32, 32)], 0)
    out.loss.backward()
    return out.loss.detach(), images.grad


def test_hub_folder_layout(hub_folders):
    base, control = hub_folders
    assert (base / "model_index.json").is_file()
    for part in ("unet", "vae", "text_encoder", "tokenizer", "scheduler"):
        assert (base / part).is_dir()
    assert (control / "config.json").is_file()
    assert models.missing_base_parts(base) == []
    assert models.missing_controlnet_parts(control) == []


def test_loading_from_local_folders_matches_the_in_process_models(hub_folders):
    base, control = hub_folders
    loaded = StableDiffusionDepthGuidance(
        base_model=base, controlnet=control, resolution=RES, device="cpu", seed=0
    )
    direct = StableDiffusionDepthGuidance(
        components=tiny_models(seed=3), resolution=RES, device="cpu", seed=0
    )
    assert loaded.dtype == torch.float32
    la, ga = sds_loss(loaded)
    lb, gb = sds_loss(direct)
    assert torch.equal(la, lb)
    assert torch.equal(ga, gb)


def test_missing_hub_model_offline_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "empty-cache"))
    start = time.monotonic()
    with pytest.raises(ModelNotFoundError) as info:
        StableDiffusionDepthGuidance(base_model="stabilityai/stable-diffusion-2-1-base")
    assert time.monotonic() - start < 60  # no network wait (generous bound for a loaded machine)
    msg = str(info.value)
    assert "Stable Diffusion base model not found" in msg
    assert "stabilityai/stable-diffusion-2-1-base" in msg
    assert "offline" in msg
    assert "hf download stabilityai/stable-diffusion-2-1-base --local-dir" in msg
    assert "--base-model" in msg


def test_partial_folder_names_what_is_missing(hub_folders, tmp_path):
    import shutil

    base, control = hub_folders
    partial = tmp_path / "sd"
    shutil.copytree(base, partial)
    for f in (partial / "unet").glob("*.safetensors"):
        f.unlink()
    shutil.rmtree(partial / "tokenizer")
    with pytest.raises(ModelNotFoundError) as info:
        StableDiffusionDepthGuidance(base_model=partial, controlnet=control)
    msg = str(info.value)
    assert "incomplete" in msg and "unet/ weights" in msg and "tokenizer/" in msg
    assert "--base-model" in msg


def test_missing_controlnet_folder_is_a_clear_error(hub_folders, tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    base, _ = hub_folders
    (tmp_path / "cn").mkdir()
    with pytest.raises(
        ModelNotFoundError, match=r"depth ControlNet.*missing config.json.*--controlnet"
    ):
        StableDiffusionDepthGuidance(base_model=base, controlnet=tmp_path / "cn")
    with pytest.raises(ModelNotFoundError, match="depth ControlNet not found"):
        StableDiffusionDepthGuidance(base_model=base, controlnet="nobody/no-such-controlnet")


def test_unreachable_hub_means_local_files_only(monkeypatch):
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.delenv("TRANSFORMERS_OFFLINE", raising=False)
    monkeypatch.setattr(models, "hub_reachable", lambda timeout=3.0: False)
    assert models.local_files_only(["stabilityai/stable-diffusion-2-1-base"])
    monkeypatch.setattr(models, "hub_reachable", lambda timeout=3.0: True)
    assert not models.local_files_only(["stabilityai/stable-diffusion-2-1-base"])
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    assert models.local_files_only(["stabilityai/stable-diffusion-2-1-base"])


def test_hub_probe_returns_within_its_timeout(monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://10.255.255.1:9")  # unroutable
    start = time.monotonic()
    assert models.hub_reachable(timeout=0.5) is False
    assert time.monotonic() - start < 5.0


# -- LoRA ---------------------------------------------------------------------------------


def random_lora_state_dict(unet, rank=4, seed=0, prefix="unet.", old_layout=False):
    """A LoRA in diffusers' file format for every attention projection of ``unet``."""
    g = torch.Generator().manual_seed(seed)
    sd = {}
    for name, module in unet.named_modules():
        if not isinstance(module, torch.nn.Linear):
            continue
        if not name.endswith(
            (
                "attn1.to_q",
                "attn1.to_k",
                "attn1.to_v",
                "attn1.to_out.0",
                "attn2.to_q",
                "attn2.to_k",
                "attn2.to_v",
                "attn2.to_out.0",
            )
        ):
            continue
        down = torch.randn(rank, module.in_features, generator=g) * 0.1
        up = torch.randn(module.out_features, rank, generator=g) * 0.1
        if old_layout:  # attention-processor layout of diffusers <= 0.20
            parts = name.removesuffix(".0").split(".")
            key = f"{prefix}{'.'.join(parts[:-1])}.processor.{parts[-1]}_lora"
        else:
            key = f"{prefix}{name}.lora"
        sd[f"{key}.down.weight"] = down
        sd[f"{key}.up.weight"] = up
    return sd


def unet_output(unet):
    g = torch.Generator().manual_seed(9)
    x, emb = torch.randn(1, 4, 8, 8, generator=g), torch.randn(1, 77, 32, generator=g)
    with torch.no_grad():
        return unet(x, torch.tensor([400]), emb).sample


def expected_lora_output(sd, prefix="unet."):
    """The UNet output with W + up @ down folded in by hand (the LoRA definition, alpha = rank)."""
    parts = tiny_models()
    modules = dict(parts.unet.named_modules())
    with torch.no_grad():
        for key, down in sd.items():
            if not key.endswith(".lora.down.weight"):
                continue
            name = key[len(prefix) : -len(".lora.down.weight")]
            modules[name].weight += sd[key.replace(".down.", ".up.")] @ down
    return unet_output(parts.unet)


@pytest.mark.parametrize("prefix", ["unet.", ""])
def test_lora_file_loads_and_changes_the_unet_exactly_as_defined(tmp_path, prefix):
    sd = random_lora_state_dict(tiny_models().unet, prefix=prefix)
    save_file(sd, tmp_path / "pytorch_lora_weights.safetensors")
    parts = tiny_models()
    before = unet_output(parts.unet)
    added = load_lora(parts.unet, tmp_path)  # the folder form
    assert added == len(sd) // 2
    after = unet_output(parts.unet)
    assert (after - before).abs().max() > 1e-3
    torch.testing.assert_close(after, expected_lora_output(sd, prefix), rtol=1e-4, atol=1e-5)


def test_old_attention_processor_layout_loads(tmp_path):
    new = random_lora_state_dict(tiny_models().unet, seed=4)
    old = random_lora_state_dict(tiny_models().unet, seed=4, old_layout=True)
    assert any(".processor.to_out_lora.up.weight" in k for k in old)
    a, b = tiny_models(), tiny_models()
    load_lora(a.unet, new)
    save_file(old, tmp_path / "old.safetensors")
    load_lora(b.unet, tmp_path / "old.safetensors")
    torch.testing.assert_close(unet_output(a.unet), unet_output(b.unet))


def test_guidance_with_lora_differs_and_scale_zero_switches_it_off(tmp_path):
    sd = random_lora_state_dict(tiny_models().unet, seed=2)
    save_file(sd, tmp_path / "bean.safetensors")
    plain = StableDiffusionDepthGuidance(components=tiny_models(), resolution=RES, device="cpu")
    with_lora = StableDiffusionDepthGuidance(
        components=tiny_models(), resolution=RES, device="cpu", lora=tmp_path / "bean.safetensors"
    )
    off = StableDiffusionDepthGuidance(
        components=tiny_models(),
        resolution=RES,
        device="cpu",
        lora=tmp_path / "bean.safetensors",
        lora_scale=0.0,
    )
    assert count_lora_layers(with_lora.parts.unet) == len(sd) // 2
    la, lb, lc = sds_loss(plain)[0], sds_loss(with_lora)[0], sds_loss(off)[0]
    assert la.item() != lb.item()
    torch.testing.assert_close(la, lc)


def test_lora_errors(tmp_path):
    unet = tiny_models().unet
    with pytest.raises(ModelNotFoundError, match="lora train"):
        load_lora(unet, tmp_path / "missing")
    with pytest.raises(ModelNotFoundError, match="no pytorch_lora_weights"):
        load_lora(unet, tmp_path)
    (tmp_path / "junk.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(InputError, match="cannot read"):
        load_lora(unet, tmp_path / "junk.safetensors")
    wrong = random_lora_state_dict(unet)
    wrong = {
        k: torch.cat([v, v], dim=-1) if k.endswith("down.weight") else v for k, v in wrong.items()
    }
    with pytest.raises(InputError, match="does not fit"):
        load_lora(tiny_models().unet, wrong)
    with pytest.raises(InputError, match=r"does not fit|matched"):
        load_lora(
            tiny_models().unet,
            {
                "unet.nowhere.to_q.lora.down.weight": torch.zeros(4, 8),
                "unet.nowhere.to_q.lora.up.weight": torch.zeros(8, 4),
            },
        )
    with pytest.raises(InputError, match="not a LoRA"):
        load_lora(tiny_models().unet, {"unet.conv_in.weight": torch.zeros(1)})
