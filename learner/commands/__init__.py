"""The `morphmimic` commands that are not a training run, an evaluation or a benchmark: one
module per command, each with its options dataclass and `main(argv)`."""
