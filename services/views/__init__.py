"""What the viewers show: the Rerun entity tree and blueprints, and the Foxglove layout.

Shared by the live monitor (`services.monitor`, which logs the entities) and the recorder
(`services.recording`, which attaches a layout and a blueprint to every recording).
"""
