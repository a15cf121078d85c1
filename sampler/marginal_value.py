"""The marginal value function Vm(s_b) and its running average Vbar (Won & Lee 2019, Sec. 4.2).

Vm(s_b) = integral of V(s_b, s_d, s_s) over everything but the parameters s_b (their Eq. 8): the
return the current policy expects for a body shape (or any task parameter). It is learned as a
small network regressed on the (s_b, V(s)) pairs collected during rollouts (Algorithm 1, lines
15-16) and updated with minibatches of them after each policy update, together with its average
Vbar (lines 24-26). Pure torch/numpy: no sockets, no processes.

Over (shape, class) (`classes` given; the sampler's `shape_by_class`, issue 55 item 2) the net
also takes the motion class one-hot, so Vm(s_b, c) is a shape function per class sharing its
hidden layers (a one-hot into the first layer is a learned per-class embedding of the first
layer's width). Each class then has its own running average Vbar_c over the box and its own
spread, which set the temperature of its buffer's density.
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator, Sequence

import numpy as np
import torch
from torch import nn


@contextlib.contextmanager
def one_torch_thread() -> Iterator[None]:
    """Run torch ops of this block on one intra-op thread, then restore the previous count.

    NOTE: a 64-wide MLP gains nothing from intra-op threads, and on a 2-core machine shared with
    simulation workers OpenMP's spin-waiting made a Vm fit 25x slower with 2 threads than with 1
    (measured: 0.36 s vs 8.6 s for 360 steps). With the OpenMP builds of torch the thread count
    is per calling thread, so the service's thread does not change the learner's setting.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


class MarginalValue:
    """Vm: an MLP over parameters normalized to the box [-1, 1]^d, plus the running average Vbar.

    NOTE: returns are O(10-200) while Adam moves weights by about `lr` per step, so regressing raw
    targets at lr 1e-3 would take 1e5 steps to reach the right offset. The network predicts
    standardized values; the mean/std of each fit's targets are folded into the output layer the
    PopArt way (van Hasselt et al. 2016) so re-standardizing never changes Vm's predictions.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray, hidden: tuple[int, ...] = (64, 64),
                 lr: float = 1e-3, vbar_rate: float = 1e-3, seed: int = 0, probe_points: int = 1024,
                 device: str | torch.device = "cpu", classes: Sequence[str] = ()):
        self.low = np.asarray(low, dtype=np.float64)
        self.high = np.asarray(high, dtype=np.float64)
        if self.low.shape != self.high.shape or self.low.ndim != 1:
            raise ValueError(f"low {self.low.shape} and high {self.high.shape} must be equal 1-D shapes")
        self.dim = self.low.shape[0]
        self.hidden = tuple(int(h) for h in hidden)
        self.classes: tuple[str, ...] = tuple(classes)
        """Motion class names, in the order of the one-hot inputs (empty: Vm over the parameters alone)."""
        if len(set(self.classes)) != len(self.classes):
            raise ValueError(f"Vm classes repeat: {list(self.classes)}")
        self.n_classes = len(self.classes)
        self.lr = lr
        self.vbar_rate = vbar_rate
        # A private RNG stream: the seed fixes Vm's init without touching the caller's torch RNG.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            layers: list[nn.Module] = []
            width = self.dim + self.n_classes
            for h in self.hidden:
                layers += [nn.Linear(width, h), nn.ReLU()]
                width = h
            layers.append(nn.Linear(width, 1))
            self.net = nn.Sequential(*layers).to(device)
        self.device = torch.device(device)
        self.opt = torch.optim.Adam(self.net.parameters(), lr=lr)
        self.seed, self.probe_points = seed, probe_points
        self.probe = self._uniform_probe()
        """`[probe_points, d]` fixed uniform points over the box: Vbar's box average, Vm's spread
        and the reported Vm range."""
        self.probe_std = 0.0
        """Std of Vm over the probe points after the last fit (value units): its spread."""
        self.mu = 0.0
        """Mean of the standardized targets (the output layer's PopArt offset), value units."""
        self.sigma = 1.0
        """Std of the standardized targets, value units."""
        self.vbar = 0.0
        """Running average of Vm (Algorithm 1, line 26); 0 until the first fit."""
        self.vbar_c = np.zeros(self.n_classes)
        """Per class: the running average of Vm(., c) over the box (Vbar_c), 0 until fitted."""
        self.probe_std_c = np.zeros(self.n_classes)
        """Per class: the std of Vm(., c) over the probe points after the last fit."""
        self.class_seen = np.zeros(self.n_classes, dtype=bool)
        """Per class: pairs of it were fitted (Vbar_c starts at its first batch's mean return)."""
        self.fitted = False
        self.steps = 0
        self.pairs_seen = 0
        self.last_loss = float("nan")

    def _uniform_probe(self) -> np.ndarray:
        return np.random.default_rng(self.seed + 1).uniform(self.low, self.high, size=(self.probe_points, self.dim))

    def normalize(self, params: np.ndarray) -> np.ndarray:
        """Map `[n, d]` parameters from the box to [-1, 1]; a zero-width dimension maps to 0."""
        span = self.high - self.low
        safe = np.where(span > 0, span, 1.0)
        return np.where(span > 0, 2.0 * (np.asarray(params, dtype=np.float64) - self.low) / safe - 1.0, 0.0)

    def _forward(self, x: torch.Tensor) -> torch.Tensor:
        """Standardized prediction `[n]` for normalized inputs `[n, d]`."""
        return self.net(x).squeeze(-1)

    def _class_index(self, classes: Any, n: int) -> np.ndarray:
        """`[n]` class indices from an int or `[n]` ints (ValueError outside [0, n_classes))."""
        if self.n_classes == 0:
            if classes is not None:
                raise ValueError("this Vm is over the parameters alone; give no classes")
            return np.zeros(0, dtype=np.int64)
        if classes is None:
            raise ValueError(f"this Vm is over (parameters, class); give a class index in [0, {self.n_classes})")
        idx = np.broadcast_to(np.asarray(classes, dtype=np.int64), (n,))
        if n and (idx.min() < 0 or idx.max() >= self.n_classes):
            raise ValueError(f"class index {int(idx.min() if idx.min() < 0 else idx.max())}; allowed: [0, {self.n_classes})")
        return idx

    def inputs(self, params: np.ndarray, classes: Any = None) -> np.ndarray:
        """The net's inputs `[n, d (+ n_classes)]`: normalized parameters and the class one-hot."""
        x = self.normalize(np.atleast_2d(params))
        idx = self._class_index(classes, x.shape[0])
        if self.n_classes == 0:
            return x
        one_hot = np.zeros((x.shape[0], self.n_classes))
        one_hot[np.arange(x.shape[0]), idx] = 1.0
        return np.concatenate([x, one_hot], axis=1)

    def __call__(self, params: np.ndarray, classes: Any = None) -> np.ndarray:
        """Vm at `[n, d]` parameters (of class `classes`: an index or `[n]` indices, when Vm is
        over classes) -> `[n]` float64, in value (return) units."""
        x = torch.as_tensor(self.inputs(params, classes), dtype=torch.float32, device=self.device)
        with torch.no_grad(), one_torch_thread():
            y = self._forward(x).double().cpu().numpy()
        return self.mu + self.sigma * y

    def _restandardize(self, mu: float, sigma: float) -> None:
        """Move the target standardization to (mu, sigma) keeping every prediction unchanged."""
        last: nn.Linear = self.net[-1]
        with torch.no_grad():
            last.weight.mul_(self.sigma / sigma)
            last.bias.copy_((self.sigma * last.bias + self.mu - mu) / sigma)
        self.mu, self.sigma = mu, sigma

    def fit(self, params: np.ndarray, values: np.ndarray, steps: int, minibatch: int,
            rng: np.random.Generator, classes: np.ndarray | None = None) -> float:
        """Regress Vm on pairs (Algorithm 1, lines 24-26): `steps` Adam steps on minibatches of
        `minibatch` pairs drawn with replacement from `params [m, d]`, `values [m]`, then Vbar
        moves toward Vm's average over the box. Returns the last step's MSE (value units^2).

        Reconstruction (the OCR of line 26 is unreadable): Vbar is the average of Vm over the
        parameter domain (the normalizer of Eq. 9, under Eq. 8's uniform density), tracked at
        rate `vbar_rate` per minibatch step (paper: 1e-3): after `steps` steps
        Vbar <- Vbar + (1 - (1 - rate)^steps) (mean Vm(probe) - Vbar), probe = fixed uniform
        points. It starts at the first fit's mean return, so the first refill already has a
        sensible scale. Over classes (`classes`: `[m]` indices) each Vbar_c does the same with
        Vm(., c), starting at the mean return of its class's first pairs.

        NOTE: averaging Vm over the *collected* parameters instead would feed back: the buffer
        concentrates on hard shapes, their low values lower Vbar, which sharpens the density,
        which concentrates the buffer further.
        """
        params = np.asarray(params, dtype=np.float64).reshape(-1, self.dim)
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if params.shape[0] != values.shape[0]:
            raise ValueError(f"{params.shape[0]} parameter rows for {values.shape[0]} values; they must match")
        m = values.shape[0]
        cls = self._class_index(classes, m) if self.n_classes else None
        if m == 0 or steps <= 0:
            return self.last_loss
        mean, std = float(values.mean()), float(values.std())
        # NOTE: the floor keeps a constant-return batch from dividing by ~0.
        self._restandardize(mean, max(std, 1e-3 * max(1.0, abs(mean))))
        if not self.fitted:
            self.vbar = mean
            self.vbar_c[:] = mean
            self.fitted = True
        if cls is not None:
            sums, counts = np.bincount(cls, values, self.n_classes), np.bincount(cls, minlength=self.n_classes)
            new = (counts > 0) & ~self.class_seen
            self.vbar_c[new] = sums[new] / counts[new]
            self.class_seen |= counts > 0
        x_all = torch.as_tensor(self.inputs(params, cls), dtype=torch.float32, device=self.device)
        y_all = torch.as_tensor((values - self.mu) / self.sigma, dtype=torch.float32, device=self.device)
        loss = torch.zeros(())
        with one_torch_thread():
            for _ in range(steps):
                idx = torch.as_tensor(rng.integers(0, m, size=minibatch), device=self.device)
                pred = self._forward(x_all[idx])
                loss = torch.mean((pred - y_all[idx]) ** 2)
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                self.opt.step()
        probe_vm = self.probe_values()
        box_mean, self.probe_std = float(probe_vm.mean()), float(probe_vm.std())
        rate = 1.0 - (1.0 - self.vbar_rate) ** steps
        self.vbar += rate * (box_mean - self.vbar)
        if self.n_classes:
            self.probe_std_c = probe_vm.std(axis=1)
            self.vbar_c += rate * (probe_vm.mean(axis=1) - self.vbar_c)
        self.steps += steps
        self.pairs_seen += m
        self.last_loss = float(loss.detach()) * self.sigma**2
        return self.last_loss

    def probe_values(self) -> np.ndarray:
        """Vm at the probe points: `[probe_points]`, or `[n_classes, probe_points]` over classes."""
        if not self.n_classes:
            return self(self.probe)
        p = len(self.probe)
        return self(np.tile(self.probe, (self.n_classes, 1)), np.repeat(np.arange(self.n_classes), p)).reshape(
            self.n_classes, p)

    def temperature(self, floor: float, c: int | None = None) -> float:
        """The scale of exp(-k Vm / Vbar): |Vbar|, but at least Vm's spread over the box (its std
        on the probe points) and `floor`.

        NOTE: the paper assumes Vm, Vbar > 0 (bell-shaped rewards, discount < 1), which fails
        early in training or with penalty rewards. A negative Vbar would flip the density and
        favour the best-controlled shapes, so its magnitude is used. When |Vbar| is small next to
        Vm's spread (an untrained value net, or the average passing through 0), k * dVm / |Vbar|
        is huge and Metropolis-Hastings turns into a hill-climb: the buffer becomes a few dozen
        copies of the worst shapes (acceptance 0.02, 53 distinct of 1000 in a 5-D test). The
        spread bounds the density ratio between shapes 2 std apart to about exp(4k). Whenever
        |Vbar| exceeds the spread (a trained policy: Vbar 228, std about 100) this is the paper's
        density unchanged.

        Of class `c` (Vm over classes): the same with Vbar_c and Vm(., c)'s spread, so each
        class's buffer is as sharp relative to its own returns whatever the other classes earn.
        """
        if c is not None:
            return max(abs(float(self.vbar_c[c])), float(self.probe_std_c[c]), floor)
        return max(abs(self.vbar), self.probe_std, floor)

    def state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta of primitives, arrays) holding the net, Adam's moments, the probe points, the
        standardization and Vbar."""
        meta = {"hidden": list(self.hidden), "mu": self.mu, "sigma": self.sigma, "vbar": self.vbar,
                "fitted": self.fitted, "steps": self.steps, "pairs_seen": self.pairs_seen,
                "last_loss": self.last_loss, "probe_std": self.probe_std,
                "low": self.low.tolist(), "high": self.high.tolist(), "classes": list(self.classes),
                "vbar_c": self.vbar_c.tolist(), "probe_std_c": self.probe_std_c.tolist(),
                "class_seen": self.class_seen.tolist()}
        arrays = {f"net/{k}": v.detach().cpu().numpy().copy() for k, v in self.net.state_dict().items()}
        arrays["probe"] = self.probe.copy()
        for i, st in self.opt.state_dict()["state"].items():
            for key, val in st.items():
                arrays[f"adam/{i}/{key}"] = torch.as_tensor(val).detach().cpu().numpy().copy()
        return meta, arrays

    def load_state(self, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> bool:
        """Restore what `state` returned; raises ValueError if the layer sizes differ.

        The state may come from another box (a curriculum resumed at a new `shape_box_scale`):
        the net's input layer is re-expressed for this box so Vm keeps its value at every shape,
        and the probe points are drawn over this box (Vbar is Vm's average over the box being
        trained). Returns True when the box changed. A state saved without its box cannot be
        re-expressed; its probe points are redrawn over this box.

        The state may also be over other classes (`classes_changed` says so): a class both know
        keeps its input and its Vbar_c; a new one starts as the saved classes' average (over no
        saved classes: the saved Vm of the parameters alone, and its Vbar); a Vm over no classes
        from a state over classes is their average."""
        if tuple(meta["hidden"]) != self.hidden:
            raise ValueError(f"saved Vm has hidden sizes {meta['hidden']}, this one {list(self.hidden)}; "
                             "construct it with the saved vm_hidden")
        saved_classes = [str(c) for c in meta.get("classes", [])]
        net_state = {k[4:]: torch.tensor(np.array(v)) for k, v in arrays.items() if k.startswith("net/")}
        adam = {key: torch.tensor(np.array(val)) for key, val in arrays.items() if key.startswith("adam/")}
        self.vbar = float(meta["vbar"])
        if saved_classes != list(self.classes):
            self._remap_classes(saved_classes, net_state, adam, meta)
        else:
            self.vbar_c = np.array(meta.get("vbar_c", []), dtype=np.float64).reshape(self.n_classes)
            self.probe_std_c = np.array(meta.get("probe_std_c", []), dtype=np.float64).reshape(self.n_classes)
            self.class_seen = np.array(meta.get("class_seen", []), dtype=bool).reshape(self.n_classes)
        self.net.load_state_dict(net_state)
        self.probe = np.array(arrays["probe"], dtype=np.float64).reshape(-1, self.dim)
        opt_state = self.opt.state_dict()
        opt_state["state"] = {}
        for key, val in adam.items():
            _, i, name = key.split("/")
            opt_state["state"].setdefault(int(i), {})[name] = val
        self.opt.load_state_dict(opt_state)
        self.mu, self.sigma = float(meta["mu"]), float(meta["sigma"])
        self.fitted, self.steps = bool(meta["fitted"]), int(meta["steps"])
        self.pairs_seen, self.last_loss = int(meta["pairs_seen"]), float(meta["last_loss"])
        self.probe_std = float(meta.get("probe_std", 0.0))
        if "low" not in meta:  # a state saved without its box: its box is unknown
            self.probe = self._uniform_probe()
            return False
        old_low, old_high = np.asarray(meta["low"], np.float64), np.asarray(meta["high"], np.float64)
        if old_low.shape != self.low.shape:
            raise ValueError(f"saved Vm is over {old_low.shape[0]} parameters, this one over {self.dim}")
        if np.array_equal(old_low, self.low) and np.array_equal(old_high, self.high):
            return False
        self._reexpress_inputs(old_low, old_high)
        self.probe = self._uniform_probe()
        return True

    def _remap_classes(self, saved: list[str], net_state: dict[str, torch.Tensor], adam: dict[str, torch.Tensor],
                       meta: dict[str, Any]) -> None:
        """Rewrite a saved first layer (and its Adam moments) over `saved` classes for this Vm's
        classes, and carry Vbar_c over by name (see `load_state`)."""
        w = net_state.get("0.weight")
        if w is None or w.ndim != 2 or w.shape[1] != self.dim + len(saved):
            raise ValueError(f"saved Vm's first layer does not take {self.dim} parameters and {len(saved)} classes")
        cols = w[:, self.dim:].double()
        mean_col = cols.mean(dim=1) if len(saved) else torch.zeros(w.shape[0], dtype=torch.float64)
        new_cols = [cols[:, saved.index(c)] if c in saved else mean_col for c in self.classes]
        net_state["0.weight"] = torch.cat([w[:, :self.dim].double(), *(c[:, None] for c in new_cols)], dim=1).float()
        if not self.classes and saved:  # the average class, folded into the bias
            net_state["0.bias"] = (net_state["0.bias"].double() + mean_col).float()
        for name in ("exp_avg", "exp_avg_sq"):  # the moved columns start without moments
            key = f"adam/0/{name}"
            if key in adam:
                m = torch.zeros(w.shape[0], self.dim + self.n_classes, dtype=adam[key].dtype)
                m[:, :self.dim] = adam[key][:, :self.dim]
                adam[key] = m
        old_vbar = np.array(meta.get("vbar_c", [self.vbar] * len(saved)), dtype=np.float64).reshape(len(saved))
        old_std = np.array(meta.get("probe_std_c", [0.0] * len(saved)), dtype=np.float64).reshape(len(saved))
        old_seen = np.array(meta.get("class_seen", [False] * len(saved)), dtype=bool).reshape(len(saved))
        fallback = float(old_vbar.mean()) if len(saved) else self.vbar
        self.vbar_c = np.array([old_vbar[saved.index(c)] if c in saved else fallback for c in self.classes])
        self.probe_std_c = np.array([old_std[saved.index(c)] if c in saved else float(meta.get("probe_std", 0.0))
                                     for c in self.classes])
        self.class_seen = np.array([bool(old_seen[saved.index(c)]) if c in saved else False for c in self.classes],
                                   dtype=bool)

    def _reexpress_inputs(self, old_low: np.ndarray, old_high: np.ndarray) -> None:
        """Fold the map from this box's normalized coordinates to the old box's into the first
        linear layer (x_old = a * x_new + b per parameter), so every shape keeps its Vm."""
        old_span, span = old_high - old_low, self.high - self.low
        safe_old = np.where(old_span > 0, old_span, 1.0)
        a = np.where((old_span > 0) & (span > 0), span / safe_old, 0.0)
        b = np.where(old_span > 0, (2.0 * (self.low - old_low) + np.where(span > 0, span, 0.0)) / safe_old - 1.0, 0.0)
        first: nn.Linear = self.net[0]
        with torch.no_grad():  # NOTE: only the parameter columns; the class one-hot columns stay as they are
            w = first.weight[:, :self.dim].double()
            first.bias.add_((w @ torch.as_tensor(b, device=w.device)).float())
            first.weight[:, :self.dim] = (w * torch.as_tensor(a, device=w.device)).float()
