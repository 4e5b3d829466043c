"""Interface of the seft node graph (topics, QoS, conversions, parameter schema, errors)."""
