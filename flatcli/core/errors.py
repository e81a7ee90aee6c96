"""The core's one domain exception: bad input or an impossible request, said in one line."""


class FlatcliError(ValueError):
    """A domain error with a message fit to show a user as one line."""
