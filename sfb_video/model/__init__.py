"""The image formation model of Shape from Blur and what builds on it."""
