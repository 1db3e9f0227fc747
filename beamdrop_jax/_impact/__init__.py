"""The housing's landing: the rigid impact law (`routh.py`), the housing's kinematics (`kinematics.py`), clattering (`clatter.py`) and the supports' motion it gives the board (`motion.py`)."""
