"""Expressions -> larynx slide (paper Sec. 6.1, Fig. 6): an autoregressive transformer in
the manner of FaceFormer (Fan et al. 2022), and the larynx tracker of Eq. 13.

Model (:class:`LarynxTransformer`): the expressions are encoded by a causal temporal
convolution over the last ``window`` frames (FaceFormer's audio encoder has temporal
convolutions too; the larynx follows the mouth with a lag, so frame k's code holds psi
k - window + 1 .. k); the past slides tau_1..tau_{k-1} (a learned start token first) are
embedded, given FaceFormer's periodic positional encoding, and decoded by causal
self-attention and by cross-attention to the expression codes under FaceFormer's alignment
mask (frame k reads code k only). A linear head gives tau_k. Training feeds the true past
(teacher forcing) with noise added, so the model does not learn to copy its last output;
prediction feeds back its own outputs.

Weights and the resumable training checkpoint are ``.npz`` files of named arrays (the
model's and Adam's tensors, the step, the data's scale) plus a JSON ``meta`` string; no
pickle.

Eq. 13 (:func:`track_larynx`): the larynx's vertical position in normal maps is where a
generic larynx kernel (70 x 70 x 3 normals) responds most, minus its rest position.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.io.npz import write_npz

FORMAT = "hack-larynx-motion"
#: tau is learned in centimetres (numbers of order 1).
TAU_SCALE = 100.0


@dataclass(frozen=True)
class LarynxConfig:
    """Sizes of the transformer and of its training."""

    num_expressions: int
    d_model: int = 64
    heads: int = 4
    layers: int = 2
    window: int = 12
    period: int = 30
    steps: int = 1500
    batch: int = 16
    crop: int = 64
    lr: float = 1e-3
    feedback_noise_cm: float = 0.05
    seed: int = 0

    def __post_init__(self):
        if self.num_expressions < 1 or self.d_model % self.heads or self.window < 1:
            raise HackError(f"larynx-motion: invalid sizes {self} (expressions >= 1, d_model "
                            "a multiple of heads, window >= 1).")


class PeriodicPositionalEncoding(nn.Module):
    """FaceFormer's periodic positional encoding: sinusoids of (k mod period)."""

    def __init__(self, d: int, period: int):
        super().__init__()
        pos = torch.arange(period, dtype=torch.float32)[:, None]
        div = torch.exp(torch.arange(0, d, 2, dtype=torch.float32) * (-math.log(10000.0) / d))
        pe = torch.zeros(period, d)
        pe[:, 0::2] = torch.sin(pos * div)
        pe[:, 1::2] = torch.cos(pos * div)
        self.register_buffer("pe", pe, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, T, d) -> x + PE (k mod period)."""
        k = torch.arange(x.shape[1]) % self.pe.shape[0]
        return x + self.pe[k][None]


class LarynxTransformer(nn.Module):
    """psi (B, T, E) and past tau -> tau (B, T), centimetres inside."""

    def __init__(self, cfg: LarynxConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.psi_in = nn.Conv1d(cfg.num_expressions, d, cfg.window)  # causal: left-padded
        self.tau_in = nn.Linear(1, d)
        self.start = nn.Parameter(torch.zeros(d))
        self.ppe = PeriodicPositionalEncoding(d, cfg.period)
        layer = nn.TransformerDecoderLayer(d, cfg.heads, 2 * d, dropout=0.0, batch_first=True)
        self.decoder = nn.TransformerDecoder(layer, cfg.layers)
        self.out = nn.Linear(d, 1)

    def masks(self, t: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Causal self-attention (T, T) and the alignment mask (T, T), True = blocked."""
        k = torch.arange(t)
        return k[None, :] > k[:, None], k[None, :] != k[:, None]

    def encode(self, psi: torch.Tensor) -> torch.Tensor:
        """psi (B, T, E) -> codes (B, T, d), each from frames k - window + 1 .. k (the
        first frame repeated before the start)."""
        x = psi.transpose(1, 2)
        x = torch.cat([x[..., :1].expand(-1, -1, self.cfg.window - 1), x], -1)
        return self.psi_in(x).transpose(1, 2)

    def forward(self, psi: torch.Tensor, past_tau_cm: torch.Tensor) -> torch.Tensor:
        """psi (B, T + c, E): the T frames to predict, after c >= 0 frames of context
        (read by the encoder only); past_tau_cm (B, T): tau of frames 0..T-2 at positions
        1..T-1 (position 0 is the start token; its value is ignored) -> tau (B, T) cm."""
        return self.decode(self.encode(psi)[:, psi.shape[1] - past_tau_cm.shape[1]:],
                           past_tau_cm)

    def decode(self, codes: torch.Tensor, past_tau_cm: torch.Tensor) -> torch.Tensor:
        """codes (B, T, d) of the frames to predict, past tau (B, T) -> tau (B, T) cm."""
        b, t = past_tau_cm.shape
        tok = self.tau_in(past_tau_cm[..., None])
        tok = torch.cat([self.start.expand(b, 1, -1), tok[:, 1:]], 1)
        causal, align = self.masks(t)
        h = self.decoder(self.ppe(tok), codes, tgt_mask=causal, memory_mask=align)
        return self.out(h)[..., 0]

    @torch.no_grad()
    def generate(self, psi: torch.Tensor, context: int = 128) -> torch.Tensor:
        """Autoregressive prediction: psi (T, E) -> tau (T,) cm, each frame from the
        model's own past outputs (the last ``context`` frames)."""
        t = psi.shape[0]
        codes = self.encode(psi[None])
        out = torch.zeros(t)
        for k in range(t):
            s = max(0, k + 1 - context)
            past = torch.cat([torch.zeros(1), out[s:k]])
            out[k] = self.decode(codes[:, s:k + 1], past[None])[0, -1]
        return out


def _check_pairs(pairs, where: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    psis, taus = [], []
    for i, (psi, tau) in enumerate(pairs):
        psi, tau = np.asarray(psi, np.float64), np.asarray(tau, np.float64)
        if psi.ndim != 2 or tau.shape != (len(psi),) or len(psi) < 2:
            raise HackError(f"{where} {i}: expected psi (T, E) and tau (T,), T >= 2, found "
                            f"{psi.shape} and {tau.shape}.")
        if not (np.isfinite(psi).all() and np.isfinite(tau).all()):
            raise HackError(f"{where} {i}: psi or tau contains NaN or inf.")
        psis.append(psi)
        taus.append(tau)
    if not psis or len({p.shape[1] for p in psis}) != 1:
        raise HackError(f"{where}: expected sequences with one expression count, found "
                        f"{sorted({p.shape[1] for p in psis})}.")
    return psis, taus


def _batch(psis, taus, cfg: LarynxConfig, g: torch.Generator):
    """Random crops: psi (B, W - 1 + L, E) with the W - 1 frames before each crop as the
    encoder's context (the first frame repeated before a sequence's start), tau (B, L) cm."""
    lens = np.array([len(p) for p in psis])
    crop = int(min(cfg.crop, lens.min()))
    c = cfg.window - 1
    xs, ys = [], []
    for _ in range(cfg.batch):
        i = int(torch.randint(len(psis), (1,), generator=g))
        s = int(torch.randint(len(psis[i]) - crop + 1, (1,), generator=g))
        padded = np.concatenate([np.repeat(psis[i][:1], c, 0), psis[i]])
        xs.append(padded[s:s + c + crop])
        ys.append(taus[i][s:s + crop])
    return (torch.as_tensor(np.stack(xs), dtype=torch.float32),
            torch.as_tensor(np.stack(ys), dtype=torch.float32) * TAU_SCALE)


def save_checkpoint(path: Path, model: LarynxTransformer, opt, step: int, meta: dict,
                    rng: torch.Generator | None = None) -> None:
    """Model weights, Adam's state, the batch generator's state and the step as named
    arrays (atomic write)."""
    arrays = {f"model/{k}": v.detach().numpy() for k, v in model.state_dict().items()}
    if rng is not None:
        arrays["rng_state"] = rng.get_state().numpy()
    if opt is not None:
        for i, st in opt.state_dict()["state"].items():
            for k, v in st.items():
                arrays[f"adam/{i}/{k}"] = np.asarray(v.detach().numpy() if torch.is_tensor(v) else v)
    meta = {**meta, "step": step, "config": model.cfg.__dict__}
    write_npz(path, {"meta": np.str_(json.dumps(meta)), **arrays})


def _read_npz(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except (OSError, KeyError, ValueError) as exc:
        raise HackError(f"{path}: not a larynx-motion file ({exc}); write one with "
                        "`hack-render learn larynx-motion`.") from exc
    if meta.get("format") != FORMAT:
        raise HackError(f"{path}: expected format {FORMAT!r}, found {meta.get('format')!r}.")
    return meta, arrays


def load_model(path: str | Path) -> tuple[LarynxTransformer, dict]:
    """A trained (or checkpointed) model and its meta."""
    meta, arrays = _read_npz(Path(path))
    model = LarynxTransformer(LarynxConfig(**meta["config"]))
    model.load_state_dict({k[6:]: torch.from_numpy(v.copy()) for k, v in arrays.items()
                           if k.startswith("model/")})
    return model.eval(), meta


def train(pairs, cfg: LarynxConfig, output: str | Path, resume: bool = False,
          progress: bool = True, checkpoint_every: int = 100, sources=None,
          stop_after: int | None = None) -> tuple:
    """Train on (psi (T, E), tau (T,) metres) pairs; returns (model, meta).

    The checkpoint (``output``) is written every ``checkpoint_every`` steps and at the
    end; with ``resume``, training continues from it (weights, Adam's moments, the batch
    generator, step) as if never stopped. ``stop_after`` ends the run early at that step
    (checkpointed), as an interruption would."""
    output = Path(output)
    psis, taus = _check_pairs(pairs, "training sequence")
    if psis[0].shape[1] != cfg.num_expressions:
        raise HackError(f"larynx-motion: the sequences have {psis[0].shape[1]} expressions, "
                        f"the model {cfg.num_expressions}.")
    torch.manual_seed(cfg.seed)
    model = LarynxTransformer(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    start = 0
    meta = {"format": FORMAT, "version": 1, "tau_scale": TAU_SCALE,
            "training_sequences": sources or [], "training_frames": int(sum(map(len, psis)))}
    if resume and output.is_file():
        old, arrays = _read_npz(output)
        if old["config"] != cfg.__dict__:
            raise HackError(f"--resume {output}: the checkpoint was made with {old['config']}, "
                            f"not {cfg.__dict__}; use the same options or a new -o.")
        model.load_state_dict({k[6:]: torch.from_numpy(v.copy()) for k, v in arrays.items()
                               if k.startswith("model/")})
        opt_state = opt.state_dict()
        for name, v in arrays.items():
            if name.startswith("adam/"):
                _, i, k = name.split("/")
                opt_state["state"].setdefault(int(i), {})[k] = torch.from_numpy(v.copy())
        opt.load_state_dict(opt_state)
        start = int(old["step"])
        meta["seconds"] = old.get("seconds", 0.0)
    g = torch.Generator().manual_seed(cfg.seed)
    if start and "rng_state" in arrays:  # the crops and noise an uninterrupted run draws
        g.set_state(torch.from_numpy(arrays["rng_state"].copy()))
    t0 = time.perf_counter() - meta.get("seconds", 0.0)
    end = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    bar = tqdm(range(start, end), desc="larynx-motion", unit="step",
               disable=not progress, initial=start, total=cfg.steps)
    for step in bar:
        x, y = _batch(psis, taus, cfg, g)
        past = torch.roll(y, 1, 1) + cfg.feedback_noise_cm * torch.randn(y.shape, generator=g)
        for group in opt.param_groups:  # cosine decay, a function of the step (resumable)
            group["lr"] = cfg.lr * 0.5 * (1 + math.cos(math.pi * step / cfg.steps))
        loss = ((model(x, past) - y) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        bar.set_postfix(rmse_mm=f"{10 * loss.item() ** 0.5:.3f}")
        if (step + 1) % checkpoint_every == 0 or step + 1 == end:
            meta["seconds"] = time.perf_counter() - t0
            save_checkpoint(output, model, opt, step + 1, meta, g)
    meta["seconds"] = time.perf_counter() - t0
    return model.eval(), meta


def predict(model: LarynxTransformer, psi: np.ndarray) -> np.ndarray:
    """tau (T,) metres for psi (T, E), autoregressively."""
    psi = np.asarray(psi, np.float64)
    if psi.ndim != 2 or psi.shape[1] != model.cfg.num_expressions or not np.isfinite(psi).all():
        raise HackError(f"psi: expected finite (T, {model.cfg.num_expressions}), found "
                        f"shape {psi.shape}.")
    return model.generate(torch.as_tensor(psi, dtype=torch.float32)).double().numpy() / TAU_SCALE


def fill_tau(model: LarynxTransformer, seq):
    """A parameter sequence (``geometry.params.ParamSequence``) with its tau predicted from
    its psi (an expression-only sequence, e.g. from an ARKit capture, gains a larynx)."""
    if seq.psi is None:
        raise HackError("sequence: key 'psi' is missing; the larynx is predicted from the "
                        "per-frame expressions.")
    return replace(seq, tau=predict(model, seq.psi))


def evaluate(model: LarynxTransformer, pairs) -> dict:
    """RMSE and max error (mm) of autoregressive prediction on (psi, tau) pairs, against
    tau's own standard deviation (what predicting a constant would cost)."""
    psis, taus = _check_pairs(pairs, "test sequence")
    pred = np.concatenate([predict(model, p) for p in psis])
    true = np.concatenate(taus)
    err = pred - true
    return {"frames": len(true), "rmse_mm": float(1e3 * np.sqrt((err ** 2).mean())),
            "max_mm": float(1e3 * np.abs(err).max()), "tau_std_mm": float(1e3 * true.std()),
            "correlation": float(np.corrcoef(pred, true)[0, 1])}


# ------------------------------------------------------------------------ Eq. 13 tracking
def larynx_kernel(size: int = 70, sigma_px: float = 12.0) -> np.ndarray:
    """A generic larynx as normals (size, size, 3): the normals of a Gaussian bump of
    height field (x right, y up, z towards the camera), unit length."""
    c = (size - 1) / 2
    yy, xx = np.mgrid[0:size, 0:size] - c
    h = np.exp(-(xx ** 2 + yy ** 2) / (2 * sigma_px ** 2)) * sigma_px
    gy, gx = np.gradient(h)
    n = np.stack([-gx, gy, np.ones_like(h)], -1)  # rows grow downwards: +y is up
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def track_larynx(normal_maps: np.ndarray, kernel: np.ndarray | None = None,
                 rest_row: float | None = None, metres_per_pixel: float = 1.0) -> np.ndarray:
    """Eq. 13: tau per frame from normal maps (T, H, W, 3) in [-1, 1].

    The response ``[k * n](x)`` (the kernel's dot product with the map around x, summed
    over the 3 channels; the flat-skin part (0, 0, 1) removed from both so that flat skin
    gives no response) is maximised over x (to a fraction of a pixel: a parabola through
    the peak's column); tau is the maximum's height above ``rest_row`` (default: frame
    0's) in metres (``metres_per_pixel``), up positive. Maps: x right, y up, z towards
    the camera (the renderer's OpenCV-frame normal AOV is (x, -y, -z) of this)."""
    from scipy.signal import fftconvolve

    n = np.asarray(normal_maps, np.float64)
    if n.ndim != 4 or n.shape[-1] != 3 or not np.isfinite(n).all():
        raise HackError(f"normal maps: expected finite (T, H, W, 3), found shape {n.shape}.")
    k = larynx_kernel() if kernel is None else np.asarray(kernel, np.float64)
    if k.ndim != 3 or k.shape[-1] != 3 or k.shape[0] > n.shape[1] or k.shape[1] > n.shape[2]:
        raise HackError(f"kernel: expected (h, w, 3) no larger than the maps, found {k.shape}.")
    flat = np.array([0.0, 0.0, 1.0])
    kk = (k - flat)[::-1, ::-1]  # correlation as a convolution
    rows = []
    for frame in n - flat:
        resp = sum(fftconvolve(frame[..., c], kk[..., c], mode="same") for c in range(3))
        r, c = np.unravel_index(np.argmax(resp), resp.shape)
        off = 0.0
        if 0 < r < resp.shape[0] - 1:  # sub-pixel: the parabola through the peak's column
            a, b, d = resp[r - 1, c], resp[r, c], resp[r + 1, c]
            den = a - 2 * b + d
            off = 0.5 * (a - d) / den if den < 0 else 0.0
        rows.append(r + off)
    rows = np.asarray(rows, np.float64)
    rest = rows[0] if rest_row is None else rest_row
    return (rest - rows) * metres_per_pixel
