"""User-facing errors: each carries one sentence naming the input and what is wrong with it."""


class UserInputError(ValueError):
    """Bad input from the user (file, curve, config value). The entry points print it without a traceback."""


class ConfigError(UserInputError):
    """An impossible configuration value."""


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or infinite during training."""
