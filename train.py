"""Train a DeepCurrents model: ``python train.py experiment=minimal_trefoil [overrides]``
(the same command as ``deepcurrents-train``; see ``deepcurrents.cli.train``)."""

from deepcurrents.cli.train import main

if __name__ == "__main__":
    main()
