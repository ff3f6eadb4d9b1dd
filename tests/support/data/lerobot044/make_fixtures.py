"""Run with LeRobot 0.4.4 and the plugin at 6a529e4: saves tiny obs_act / obs_diffusion checkpoints as that
version writes them (the fixtures of tests/policies/test_old_checkpoints.py)."""
import sys, shutil
from pathlib import Path
sys.path.insert(0, "/tmp/old")
from scripts.make_synthetic_dataset import write_dataset
from tests.support.helpers import training_setup
out = Path(sys.argv[1]); data = Path("/tmp/ds044")
shutil.rmtree(data, ignore_errors=True)
write_dataset(data, episodes=2, frames=20, size=32, seed=0)
for policy_type, space in (("obs_act", "pointcloud"), ("obs_diffusion", "pointcloud")):
    extra = {"encoder": "resnet18"} if space == "rgb" else {}
    policy, pre, post, _ = training_setup(policy_type, space, data, **extra)
    target = out / policy_type
    policy.save_pretrained(target); pre.save_pretrained(target); post.save_pretrained(target)
    print(target, sum(p.numel() for p in policy.parameters()))
import torch
from safetensors.torch import save_file
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot_obsbench.policies.loading import load_policy
frame = LeRobotDataset("local/test", root=data)[5]
for policy_type in ("obs_act", "obs_diffusion"):
    policy, pre, post = load_policy(out / policy_type)
    policy.eval(); policy.reset()
    batch = pre({k: v[None] if isinstance(v, torch.Tensor) else v for k, v in frame.items() if k.startswith("observation.") or k == "task"})
    tensors = {k: v.contiguous() for k, v in batch.items() if isinstance(v, torch.Tensor)}
    torch.manual_seed(0)
    with torch.no_grad():
        action = policy.select_action(dict(tensors))
    save_file({**tensors, "expected_action": action.contiguous()}, str(out / policy_type / "reference_batch.safetensors"))
    print(policy_type, action)
