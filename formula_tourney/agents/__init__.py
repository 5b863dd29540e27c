"""Agents: a small core and one module per algorithm family, registered by name.

Modules, from the bottom up (imports go the same way):

- ``networks``: actors and critics; ``mlp_update``: the hand-written fast backward pass of the
  MLP actor and critic (autograd is its tested reference); ``noise``: OU noise and the paper's
  brake exploration; ``buffers``: replay (uniform, prioritized, n-step, windows, demonstrations).
- ``core``: what every family shares (flat weights, Adam, the update skeleton, acting, state).
- ``ddpg`` (the paper's, with its variants' options), ``td3``, ``sac``: one family each, with its
  target, losses and settings; ``families``: the registry (a new family is one module plus one
  line there); ``variants``: ``AgentConfig`` and the registered variants; ``checkpoints``: files.

docs/agents.md describes them; docs/ARCHITECTURE.md, "Adding things", what a new family touches.
"""
