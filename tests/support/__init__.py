"""What tests share: fakes of hardware and the Hub, stand-ins for RLBench, synthetic RealSense recordings and scenes,
rendered boards, toy envs, old-version fixtures (data/) and small helpers."""
