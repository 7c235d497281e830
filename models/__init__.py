"""Material recognition from cloth videos (thesis 7.5, 7.7): nets, training module, evaluation.

Clips are ``(B, T, 3, H, W)`` float in [0, 1]; logits ``(B, 54)`` over the stretch x bend
classes (``class_id = stretch_index * 9 + bend_index``).
"""
