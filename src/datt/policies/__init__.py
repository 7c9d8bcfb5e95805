"""The DATT networks (encoder, actor, critic) and loading a trained actor."""
