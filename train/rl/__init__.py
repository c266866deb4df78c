"""``gnn-mp train rl``: flags (:mod:`.args`), evaluation on validation problems (:mod:`.evaluation`),
the SB3 and TorchRL scripts (:mod:`.sb3`, :mod:`.torchrl`), buffer memory (:mod:`.memory`), :mod:`.cli`."""
