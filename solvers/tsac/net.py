"""The networks of TSAC-OCF (paper Sec. III-B, Fig. 3): a transformer state encoder, the
masked policy head (the actor, Eqs. 13 and 21) and a per-action Q head (the twin critics).

The networks know nothing about training: ``sac`` trains them, ``policy`` runs the
frozen actor inside the coalition game (the RL4CO split between policy and algorithm).

Shapes: a batch of B states, each with up to L task tokens and up to K depot tokens.
``task_mask``/``depot_mask`` are True for real tokens (False for padding);
``action_mask`` is True for the actions the deciding AAV may choose (the validity mask).
The action space is the task tokens, led, when ``NetConfig.pass_action``, by a pass token
(a depot row encoded by the depot encoder: the paper's depot action of M_t U D, "do nothing
this turn"); the other depot tokens are context only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F


@dataclass(frozen=True)
class NetConfig:
    agent_dim: int
    task_dim: int
    depot_dim: int
    d_model: int = 64
    heads: int = 4
    layers: int = 2
    feedforward: int = 128
    #: The version of the state and action space (``features.FEATURES``) the network
    #: is built for; ``pass_action``: whether a pass token leads the action space.
    features: int = 1
    pass_action: bool = False

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


def mlp(inputs: int, hidden: int, outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, outputs))


class StateEncoder(nn.Module):
    """Eq. 20's state -> one context-rich embedding per task token (H_enc of Eq. 12).

    Separate MLP encoders lift agent, task and depot features to d_model; the agent
    embedding is concatenated with every task and depot embedding and projected back to
    d_model (contextual fusion); a transformer encoder with multi-head self-attention mixes
    the tokens, padding excluded through ``src_key_padding_mask``."""

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        d = config.d_model
        self.agent = mlp(config.agent_dim, d, d)
        self.task = mlp(config.task_dim, d, d)
        self.depot = mlp(config.depot_dim, d, d)
        self.fuse = nn.Linear(2 * d, d)
        layer = nn.TransformerEncoderLayer(d, config.heads, config.feedforward, dropout=0.0,
                                           batch_first=True, norm_first=True)
        # No nested tensors: the padded positions must stay ordinary (finite) rows so that
        # batches padded to different lengths give the same numbers for the real tokens.
        self.transformer = nn.TransformerEncoder(layer, config.layers,
                                                 enable_nested_tensor=False)

    def forward(self, agent: Tensor, tasks: Tensor, task_mask: Tensor, depots: Tensor,
                depot_mask: Tensor, pass_token: Tensor | None = None) -> Tensor:
        """The encoded action tokens: the pass token (if given), then the tasks."""
        parts = [self.task(tasks), self.depot(depots)]
        masks = [task_mask, depot_mask]
        if pass_token is not None:
            parts.insert(0, self.depot(pass_token).unsqueeze(1))
            masks.insert(0, torch.ones_like(task_mask[:, :1]))
        n_actions = tasks.shape[1] + (pass_token is not None)
        tokens = torch.cat(parts, dim=1)
        context = self.agent(agent).unsqueeze(1).expand(-1, tokens.shape[1], -1)
        fused = self.fuse(torch.cat([context, tokens], dim=-1))
        real = torch.cat(masks, dim=1)
        encoded = self.transformer(fused, src_key_padding_mask=~real)
        return encoded[:, :n_actions]


class TokenHead(nn.Module):
    """A state encoder and an MLP giving one number per action token."""

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = StateEncoder(config)
        self.head = mlp(config.d_model, config.d_model, 1)

    def forward(self, obs: Mapping[str, Tensor]) -> Tensor:
        encoded = self.encoder(obs["agent"], obs["tasks"], obs["task_mask"], obs["depots"],
                               obs["depot_mask"], obs.get("pass_token"))
        return self.head(encoded).squeeze(-1)


class StackedHeads:
    """Several frozen ``TokenHead``s of one config (the twin critics) evaluated in one pass:
    a call gives ``(heads, batch, actions)``, each head's values as its own ``forward``
    gives them, to float rounding (tests/solvers/test_tsac.py holds it to that). Why: at
    plan time a decision is one small state, and torch's per-operation overhead, not
    arithmetic, is its cost, so two heads with their weights stacked cost what one does.
    For inference on the CPU only: the weights are copies, taken when it is built."""

    def __init__(self, heads: Sequence[TokenHead]) -> None:
        config = heads[0].config
        if any(head.config != config for head in heads):
            raise ValueError("stacked heads must share one config")
        if not all(layer.norm_first and layer.activation_relu_or_gelu == 1
                   for layer in heads[0].encoder.transformer.layers):
            raise ValueError("StackedHeads computes StateEncoder's pre-norm ReLU layers only")
        self.config = config
        self.eps = heads[0].encoder.transformer.layers[0].norm1.eps
        states = [head.state_dict() for head in heads]
        self.weights: dict[str, tuple[Tensor, Tensor]] = {}
        for name in states[0]:
            if not name.endswith("weight"):
                continue
            stem = name[:-len("weight")]
            weight = torch.stack([s[name] for s in states])
            bias = torch.stack([s[stem + "bias"] for s in states])[:, None, None, :]
            # Linear weights (heads, out, in) as (heads, 1, in, out), for x @ w over a batch;
            # layer-norm scales (heads, d) as (heads, 1, 1, d).
            weight = (weight.transpose(1, 2).unsqueeze(1) if weight.dim() == 3
                      else weight[:, None, None, :])
            self.weights[stem.rstrip("._")] = (weight.contiguous(), bias.contiguous())

    def _linear(self, x: Tensor, name: str) -> Tensor:
        weight, bias = self.weights[name]
        return torch.matmul(x, weight) + bias

    def _mlp(self, x: Tensor, name: str) -> Tensor:
        return self._linear(torch.relu(self._linear(x, f"{name}.0")), f"{name}.2")

    def _norm(self, x: Tensor, name: str) -> Tensor:
        scale, shift = self.weights[name]
        return F.layer_norm(x, x.shape[-1:], eps=self.eps) * scale + shift

    def __call__(self, obs: Mapping[str, Tensor]) -> Tensor:
        parts = [self._mlp(obs["tasks"], "encoder.task"), self._mlp(obs["depots"],
                                                                      "encoder.depot")]
        masks = [obs["task_mask"], obs["depot_mask"]]
        pass_token = obs.get("pass_token")
        if pass_token is not None:
            parts.insert(0, self._mlp(pass_token.unsqueeze(1), "encoder.depot"))
            masks.insert(0, torch.ones_like(obs["task_mask"][:, :1]))
        n_actions = obs["tasks"].shape[1] + (pass_token is not None)
        tokens = torch.cat(parts, dim=2)
        heads, batch, length, d = tokens.shape
        context = self._mlp(obs["agent"].unsqueeze(1), "encoder.agent")
        x = self._linear(torch.cat([context.expand_as(tokens), tokens], dim=-1), "encoder.fuse")
        real = torch.cat(masks, dim=1)
        attend = (None if bool(real.all()) else
                  real[None, :, None, None, :].expand(heads, -1, -1, -1, -1).flatten(0, 1))
        n_heads = self.config.heads
        for i in range(self.config.layers):
            layer = f"encoder.transformer.layers.{i}"
            h = self._norm(x, f"{layer}.norm1")
            qkv = self._linear(h, f"{layer}.self_attn.in_proj")
            q, k, v = qkv.view(heads * batch, length, 3, n_heads, d // n_heads).permute(
                2, 0, 3, 1, 4)
            attention = F.scaled_dot_product_attention(q, k, v, attn_mask=attend)
            attention = attention.transpose(1, 2).reshape(heads, batch, length, d)
            x = x + self._linear(attention, f"{layer}.self_attn.out_proj")
            h = self._norm(x, f"{layer}.norm2")
            x = x + self._linear(torch.relu(self._linear(h, f"{layer}.linear1")),
                                 f"{layer}.linear2")
        return self._mlp(x[:, :, :n_actions], "head").squeeze(-1)


class PolicyNet(TokenHead):
    """The actor: masked logits (Eq. 13): invalid and padded tasks get -inf, hence exactly
    zero probability after the softmax (Eq. 21)."""

    def forward(self, obs: Mapping[str, Tensor]) -> Tensor:
        return masked_logits(super().forward(obs), obs["action_mask"])

    def distribution(self, obs: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """(probabilities, log-probabilities); log-probabilities of invalid tasks are -inf."""
        logits = self(obs)
        return torch.softmax(logits, dim=-1), torch.log_softmax(logits, dim=-1)


class QNet(TokenHead):
    """A critic: the soft Q-value of choosing each task (padding and invalid entries are
    computed but never used: every loss masks them)."""


def masked_logits(logits: Tensor, action_mask: Tensor) -> Tensor:
    """Eq. 13: add M_mask (0 for valid, -inf for invalid) to the raw logits. A state with no
    valid action (a terminal state in the replay) keeps its raw logits so that the softmax
    stays finite; the losses give its value weight zero."""
    usable = action_mask | ~action_mask.any(dim=-1, keepdim=True)
    return logits.masked_fill(~usable, float("-inf"))


def expectation(probs: Tensor, values: Tensor, mask: Tensor) -> Tensor:
    """sum over the valid actions a of probs[a] * values[a], per state. Entries outside
    ``mask`` (where values may be -inf) are replaced by zero *before* the product, so that
    neither the value nor the gradient (0 * -inf) can become nan."""
    zero = torch.zeros((), dtype=values.dtype, device=values.device)
    return (probs * torch.where(mask, values, zero)).sum(dim=-1)


class State(Protocol):
    """One unpadded state: what ``features.observe`` returns."""

    agent: np.ndarray
    tasks: np.ndarray
    depots: np.ndarray
    action_mask: np.ndarray
    pass_token: np.ndarray | None


def collate(states: Sequence[State], device: torch.device | str = "cpu") -> dict[str, Tensor]:
    """Pad a batch of variable-length states to the longest one in the batch (L_max of
    Eq. 17) and build the padding masks (P_mask) and validity masks. A leading pass token
    keeps action indices as they are in each state (pass first, then its task rows)."""
    batch = len(states)
    offset = int(states[0].pass_token is not None)
    length = max(len(s.tasks) for s in states)
    depots = max(len(s.depots) for s in states)
    task_dim, depot_dim = states[0].tasks.shape[1], states[0].depots.shape[1]
    tasks = np.zeros((batch, length, task_dim), dtype=np.float32)
    depot_rows = np.zeros((batch, depots, depot_dim), dtype=np.float32)
    task_mask = np.zeros((batch, length), dtype=bool)
    depot_mask = np.zeros((batch, depots), dtype=bool)
    action_mask = np.zeros((batch, offset + length), dtype=bool)
    for i, s in enumerate(states):
        m, k = len(s.tasks), len(s.depots)
        tasks[i, :m] = s.tasks
        depot_rows[i, :k] = s.depots
        task_mask[i, :m] = True
        depot_mask[i, :k] = True
        action_mask[i, :offset + m] = s.action_mask
    arrays = {"agent": np.stack([s.agent for s in states]).astype(np.float32),
              "tasks": tasks, "task_mask": task_mask, "depots": depot_rows,
              "depot_mask": depot_mask, "action_mask": action_mask}
    if offset:
        arrays["pass_token"] = np.stack([s.pass_token for s in states]).astype(np.float32)
    return {name: torch.from_numpy(a).to(device) for name, a in arrays.items()}
