"""The Earth-Moon link (pure Python, no Drake): messages, the persistent ledger, links."""
