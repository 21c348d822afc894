"""The data fusion center: the DFC loop, independent of the transport, and an operator's
control of it."""
