"""The shared contract: keys, messages, sessions, config, clocks, logging. No domain math."""
