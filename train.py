"""Train the points-to-map network: ``python train.py dataset=procedural`` (see README and conf/train.yaml)."""

from patternshop_nn.train import main

if __name__ == "__main__":
    main()
