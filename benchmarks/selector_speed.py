"""Selector decision latency for the whole library, and training speed of each learned model, at the default sizes.

Run: python benchmarks/selector_speed.py [--decisions 20] [--frames 512] [--skip-training]
Latency: one decision over the library's controllers (all applicable: the worst case) at n = 10 and K = 16,
batched and one controller at a time, against the reference of encoding one camera image with the VAE in the
same process; then what the futures' decoding and scoring alone takes, with its arithmetic and the time that
arithmetic takes at the best matrix-product rate measured in the same run, and the scaling with the number of
applicable controllers and with a batch of states; then the same with the goal score of the latent
(`compose --goal-score latent`), which scores the futures without decoding them. Training: seconds
per epoch over `--frames` random frames for each model at its default configuration, and the time of a full
default training run at the datasets' sizes (frames given on the command line). Models are randomly
initialised: speed does not depend on the weights.
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.policies.library import all_names
from policy_composer.selector.configuration import DynamicsConfig, GoalScoreConfig, LatentGoalScoreConfig, VAEConfig
from policy_composer.selector.dynamics import LatentDynamics
from policy_composer.selector.goal_score import GoalScoreModel, LatentGoalScoreModel
from policy_composer.selector.vae import VAE
from policy_composer.selector.world_model import WorldModel


def timed(fn, repeat: int) -> float:
    fn()  # warm-up
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat


def scoring_flops(world: WorldModel, futures: torch.Tensor) -> int:
    """Floating-point operations of decoding and scoring `futures`, as torch counts them."""
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        world.score(futures)
    return counter.get_total_flops()


def matmul_flops_per_second(repeat: int, sizes: tuple[int, ...] = (512, 1024, 2048)) -> float:
    """The best float32 matrix-product rate torch reaches on this CPU (the fastest of `repeat` products at each size):
    dense arithmetic's practical ceiling, which convolutions seldom pass."""
    best = 0.0
    for n in sizes:
        a, b = torch.randn(n, n), torch.randn(n, n)
        a @ b
        for _ in range(repeat):
            t0 = time.perf_counter()
            a @ b
            best = max(best, 2 * n ** 3 / (time.perf_counter() - t0))
    return best


def epoch_seconds(step, frames: int, batch: int) -> float:
    """Seconds of one epoch of `step(batch)` (forward, backward, update) over `frames` frames."""
    n = max(1, frames // batch)
    return timed(lambda: [step(batch) for _ in range(n)], 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--decisions", type=int, default=20)
    parser.add_argument("--frames", type=int, default=512, help="frames per timed epoch")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rollout-frames", type=int, default=12000, help="controller-rollout frames (VAE, dynamics)")
    parser.add_argument("--demo-frames", type=int, default=700, help="training full-task demo frames (goal score)")
    parser.add_argument("--insertion-frames", type=int, default=2724, help="insertion demo frames (CNN policy)")
    parser.add_argument("--skip-training", action="store_true", help="the decision latency only")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    vae_config, dyn_config, goal_config = VAEConfig(), DynamicsConfig(), GoalScoreConfig(camera=VAEConfig().camera)
    vae = VAE(vae_config).eval()
    names = all_names()
    dynamics = {n: LatentDynamics(DynamicsConfig(controller=n)).eval() for n in names}
    world = WorldModel(vae, dynamics, GoalScoreModel(goal_config).eval())
    latent_goal = LatentGoalScoreModel(LatentGoalScoreConfig(latent_dim=vae_config.latent_dim)).eval()
    latent_world = WorldModel(vae, dynamics, latent_goal)
    obs = {"sensor_data": {world.camera: {"rgb": torch.randint(0, 255, (1, 128, 128, 3), dtype=torch.uint8)}}}
    encode = timed(lambda: world.encode(obs), args.decisions)
    W, K = len(names), 16
    print(f"reference: encode one 128x128 image with the VAE: {encode * 1000:.1f} ms")

    def decision(batched: bool, applicable: int = W, states: int = 1, model: WorldModel = world) -> float:
        selector = model.selector(horizon=10, samples=K, seed=0, batched=batched)
        mask = torch.zeros(states, W, dtype=torch.bool)
        mask[:, :applicable] = True
        z = world.encode(obs).expand(states, -1)
        return timed(lambda: selector.decide(z, mask), args.decisions)

    batched, one_by_one = decision(True), decision(False)
    print(f"selector decision, {W} controllers applicable, n = 10, K = {K}: {batched * 1000:.0f} ms batched "
          f"({batched / encode:.0f}x the reference), {one_by_one * 1000:.0f} ms one controller at a time "
          f"(batching: {one_by_one / batched:.1f}x faster); target 10 ms: {'met' if batched <= 0.010 else 'not met'}")
    futures = torch.randn(W * K, vae_config.latent_dim)
    with torch.no_grad():
        folded, plain = (timed(lambda d=d: d(futures), args.decisions) for d in (world.decoder, vae.decode))
    scoring = timed(lambda: world.score(futures), args.decisions)
    print(f"  of which decoding and scoring the {W * K} futures: {scoring * 1000:.0f} ms (decoding: "
          f"{folded * 1000:.0f} ms folded, {plain * 1000:.0f} ms with the VAE's own decode)")
    flops, rate = scoring_flops(world, futures), matmul_flops_per_second(args.decisions)
    print(f"  decoding and scoring's arithmetic: {flops / 1e9:.2f} GFLOP; at the best float32 matrix-product rate "
          f"measured now ({rate / 1e9:.0f} GFLOP/s) it would take {flops / rate * 1000:.0f} ms; it runs at "
          f"{flops / scoring / 1e9:.0f} GFLOP/s ({flops / scoring / rate:.0%} of that rate); 10 ms needs "
          f"{flops / 0.010 / 1e9:.0f} GFLOP/s")
    print("  by applicable controllers: " + ", ".join(
        f"{w}: {decision(True, w) * 1000:.0f} ms" for w in (1, 3, 5, W)))
    print("  by a batch of states (all applicable): " + ", ".join(
        f"{b}: {(t := decision(True, W, b)) * 1000:.0f} ms ({t / b * 1000:.0f} ms a state)" for b in (1, 2, 4)))
    latent = decision(True, model=latent_world)
    print(f"selector decision with the latent goal score, {W} controllers applicable, n = 10, K = {K}: "
          f"{latent * 1000:.1f} ms ({latent / encode:.2f}x the reference, {batched / latent:.0f}x faster than "
          f"decoding); target 10 ms: {'met' if latent <= 0.010 else 'not met'}")
    print("  by applicable controllers: " + ", ".join(
        f"{w}: {decision(True, w, model=latent_world) * 1000:.1f} ms" for w in (1, 3, 5, W)))
    print("  by a batch of states (all applicable): " + ", ".join(
        f"{b}: {(t := decision(True, W, b, latent_world)) * 1000:.1f} ms ({t / b * 1000:.1f} ms a state)"
        for b in (1, 4, 16, 64)))

    if args.skip_training:
        return
    size = vae_config.image_size
    images = torch.rand(max(vae_config.batch_size, goal_config.batch_size, 120), 3, size, size)

    def fit(model, loss_fn):
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)

        def step(b):
            loss = loss_fn(b)
            opt.zero_grad()
            loss.backward()
            opt.step()
        return step

    cnn, cnn_bf16 = CNNPolicy(CNNPolicyConfig()), CNNPolicy(CNNPolicyConfig(precision="bfloat16"))

    def cnn_loss(model, b):  # the VAE's image size is the policy's
        state, action = torch.randn(b, model.config.state_dim), torch.randn(b, model.config.action_dim)
        return model.loss(images[:b], state, action, torch.randn(b, 3))

    dyn = LatentDynamics(dyn_config)
    goal = GoalScoreModel(goal_config)
    z = torch.randn(max(dyn_config.batch_size, LatentGoalScoreConfig().batch_size), vae_config.latent_dim)
    runs = {
        "VAE": (fit(vae.train(), lambda b: vae.loss(images[:b])[0]), vae_config.batch_size, vae_config.epochs,
                args.rollout_frames),
        "dynamics model (one controller)": (fit(dyn, lambda b: dyn.loss(z[:b], z[:b] + 0.1, vae, images[:b])),
                                            dyn_config.batch_size, dyn_config.epochs,
                                            args.rollout_frames // len(all_names())),
        "goal score (one camera)": (fit(goal, lambda b: goal.loss(images[:b], torch.rand(b))), goal_config.batch_size,
                                    goal_config.epochs, 2 * args.demo_frames),
        "latent goal score": (fit(latent_goal.train(), lambda b: latent_goal.loss(z[:b], torch.rand(b))),
                              LatentGoalScoreConfig().batch_size, LatentGoalScoreConfig().epochs, args.demo_frames),
        "CNN policy": (fit(cnn, lambda b: cnn_loss(cnn, b)), CNNPolicyConfig().batch_size, CNNPolicyConfig().epochs,
                       args.insertion_frames),
        "CNN policy, bfloat16 convolutions (--precision bfloat16)": (
            fit(cnn_bf16, lambda b: cnn_loss(cnn_bf16, b)), CNNPolicyConfig().batch_size, CNNPolicyConfig().epochs,
            args.insertion_frames),
    }
    for name, (step, batch, epochs, frames) in runs.items():
        per_epoch = epoch_seconds(step, args.frames, batch)
        full = per_epoch * frames / args.frames * epochs
        print(f"training {name}: {per_epoch / args.frames * 1000:.2f} ms/frame-epoch; default run "
              f"({epochs} epochs x {frames} frames): {full / 60:.1f} min")


if __name__ == "__main__":
    main()
