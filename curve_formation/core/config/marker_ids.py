"""The predefined ArUco dictionaries by name, with how many marker ids each holds, as OpenCV's
cv2.aruco defines them: what an experiment file is checked against, without OpenCV (a test
holds this table against cv2.aruco).
"""

MARKER_IDS = {
    'DICT_4X4_50': 50, 'DICT_4X4_100': 100, 'DICT_4X4_250': 250, 'DICT_4X4_1000': 1000,
    'DICT_5X5_50': 50, 'DICT_5X5_100': 100, 'DICT_5X5_250': 250, 'DICT_5X5_1000': 1000,
    'DICT_6X6_50': 50, 'DICT_6X6_100': 100, 'DICT_6X6_250': 250, 'DICT_6X6_1000': 1000,
    'DICT_7X7_50': 50, 'DICT_7X7_100': 100, 'DICT_7X7_250': 250, 'DICT_7X7_1000': 1000,
    'DICT_ARUCO_ORIGINAL': 1024, 'DICT_ARUCO_MIP_36H12': 250,
    'DICT_APRILTAG_16H5': 30, 'DICT_APRILTAG_25H9': 35, 'DICT_APRILTAG_36H10': 2320,
    'DICT_APRILTAG_36H11': 587,
}
