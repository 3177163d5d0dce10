"""Station files shipped with magline; ``demo.yaml`` (the mock DUT) is the embedded default."""
