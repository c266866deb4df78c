"""Stable-Baselines3 features extractor: the same :class:`agents.nn.encoders.TreeEncoder`.

    from stable_baselines3 import PPO
    from agents.rl.sb3 import TreeFeaturesExtractor
    model = PPO("MultiInputPolicy", env, policy_kwargs={
        "features_extractor_class": TreeFeaturesExtractor,
        "features_extractor_kwargs": {"hidden_channels": 64, "num_layers": 3, "out_channels": 128}})

SB3 hands over the observation as a dict of float tensors with a leading batch dimension
(every Box, ``mask`` included, is cast to float); :func:`agents.nn.graph.to_pyg` accepts that.
"""

from __future__ import annotations

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from agents.nn.encoders import CandidateEncoder, encoder_from_space, prior_head_init
from agents.rl.pick import PICK_HEADS, SharedCandidateHead


class TreeFeaturesExtractor(BaseFeaturesExtractor):
    """Observation dict -> the :class:`TreeEncoder` graph embedding ``(batch, out_channels)``.

    ``features_extractor_kwargs`` go to ``TreeEncoder.from_space`` (``backbone="tree-gnn"``: the
    GNN sampler's backbone, :class:`agents.tree.backbone.TreeGNNEncoder`) (``hidden_channels``,
    ``num_layers``, ``out_channels``, ``conv``, ``knn``, ...).
    """

    def __init__(self, observation_space: spaces.Dict, **encoder_kw) -> None:
        encoder = encoder_from_space(observation_space, **encoder_kw)
        super().__init__(observation_space, features_dim=encoder.out_channels)
        self.encoder = encoder

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.encoder(observations)[1]


class CandidateFeaturesExtractor(BaseFeaturesExtractor):
    """Candidate-selection observation -> ``[per-candidate embeddings, their mean and max]``.

    For the ``Discrete(K)`` envs (``GNNMP/*-RLPick-v0``): one MLP shared by the ``K`` candidates
    reads each one's features relative to the tree (:class:`agents.nn.encoders.CandidateEncoder`);
    the flattened embeddings let ``action_net`` score each candidate slot, the mean and max
    summarise the step for the value head. ``features_extractor_kwargs``: ``hidden``, ``embed``,
    ``act``, ``tree_context`` (add a ``TreeEncoder`` embedding of the tree view; ``tree_kwargs``
    its keyword arguments)::

        model = PPO("MultiInputPolicy", gym.make("GNNMP/Maze2DRRT-RLPick-v0"),
                    policy_kwargs={"features_extractor_class": CandidateFeaturesExtractor,
                                   "net_arch": {"pi": [], "vf": [64, 64]}})
    """

    def __init__(self, observation_space: spaces.Dict, **encoder_kw) -> None:
        encoder = CandidateEncoder.from_space(observation_space, **encoder_kw)
        super().__init__(observation_space, features_dim=encoder.out_channels)
        self.encoder = encoder

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.encoder.flat(observations)


class CandidatePickPolicy(MultiInputActorCriticPolicy):
    """SB3's actor-critic for the candidate envs, with the picker's head and its prior kept intact.

    ``pick_head="shared"``: the action net is a :class:`~agents.rl.pick.SharedCandidateHead` (one
    score for all candidates, a bias per slot, the prior's scale); ``"linear"``: SB3's own slot-wise
    layer. SB3's orthogonal initialisation re-draws every linear layer under the features
    extractor, the frozen prior scorer's too: its weights are re-loaded from their checkpoint, and
    the head starts as the prior (:func:`~agents.nn.encoders.prior_head_init`). Its features
    extractor is a :class:`CandidateFeaturesExtractor` and its ``net_arch`` ``{"pi": [], "vf": [64,
    64]}`` (``gnn-mp train rl``'s defaults) unless ``policy_kwargs`` say otherwise, so that
    ``PPO(CandidatePickPolicy, env)`` and RL Zoo's ``policy: agents.rl.sb3.CandidatePickPolicy``
    (whose YAML cannot name a class) build the picker.
    """

    def __init__(self, *args, pick_head: str = "linear", **kwargs) -> None:
        if pick_head not in PICK_HEADS:
            raise ValueError(f"pick_head must be one of {PICK_HEADS}, got {pick_head!r}")
        self.pick_head = pick_head
        if kwargs.get("features_extractor_class") is None:
            kwargs["features_extractor_class"] = CandidateFeaturesExtractor
        if kwargs.get("net_arch") is None:
            kwargs["net_arch"] = {"pi": [], "vf": [64, 64]}
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        encoders = [m for m in self.modules() if isinstance(m, CandidateEncoder)]
        for encoder in encoders:
            if encoder.prior_model is not None:
                encoder.load_prior(encoder.prior_source)
        encoder = encoders[0]
        prior = encoder.prior_model is not None
        if self.pick_head == "shared":
            self.action_net = SharedCandidateHead(encoder.count, encoder.embed, prior)
        elif prior:
            prior_head_init(self.action_net, encoder.count)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "pick_head": self.pick_head}
