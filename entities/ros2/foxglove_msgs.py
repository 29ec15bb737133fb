"""The ROS 2 messages of Foxglove's 3D scene (the ``foxglove_msgs`` package, ``ros-jazzy-foxglove-msgs``), as
``.msg`` text: the fields of Foxglove's published schemas (https://docs.foxglove.dev/docs/sdk/schemas, MIT), without
their comments. rosbags' type store has no ``foxglove_msgs``: `entities.ros2.model.typestore` registers these, so
the scene is CDR like every other topic, a file holding it opens as a ROS 2 bag (rosbags reads no protobuf schema),
and Foxglove renders ``foxglove_msgs/msg/SceneUpdate`` as it renders ``foxglove.SceneUpdate``.
tests/test_ros2.py checks each definition, field by field, against foxglove-sdk's own protobuf schema of the scene.
"""

from __future__ import annotations

#: type name -> its .msg text (the types a SceneUpdate is made of).
DEFINITIONS: dict[str, str] = {
    "foxglove_msgs/msg/Color": """
float64 r
float64 g
float64 b
float64 a
""",
    "foxglove_msgs/msg/KeyValuePair": """
string key
string value
""",
    "foxglove_msgs/msg/ArrowPrimitive": """
geometry_msgs/Pose pose
float64 shaft_length
float64 shaft_diameter
float64 head_length
float64 head_diameter
foxglove_msgs/Color color
""",
    "foxglove_msgs/msg/CubePrimitive": """
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
foxglove_msgs/Color color
""",
    "foxglove_msgs/msg/SpherePrimitive": """
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
foxglove_msgs/Color color
""",
    "foxglove_msgs/msg/CylinderPrimitive": """
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
float64 bottom_scale
float64 top_scale
foxglove_msgs/Color color
""",
    "foxglove_msgs/msg/LinePrimitive": """
uint8 LINE_STRIP=0
uint8 LINE_LOOP=1
uint8 LINE_LIST=2
uint8 type
geometry_msgs/Pose pose
float64 thickness
bool scale_invariant
geometry_msgs/Point[] points
foxglove_msgs/Color color
foxglove_msgs/Color[] colors
uint32[] indices
""",
    "foxglove_msgs/msg/TriangleListPrimitive": """
geometry_msgs/Pose pose
geometry_msgs/Point[] points
foxglove_msgs/Color color
foxglove_msgs/Color[] colors
uint32[] indices
""",
    "foxglove_msgs/msg/TextPrimitive": """
geometry_msgs/Pose pose
bool billboard
float64 font_size
bool scale_invariant
foxglove_msgs/Color color
string text
""",
    "foxglove_msgs/msg/ModelPrimitive": """
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
foxglove_msgs/Color color
bool override_color
string url
string media_type
uint8[] data
""",
    "foxglove_msgs/msg/SceneEntity": """
builtin_interfaces/Time timestamp
string frame_id
string id
builtin_interfaces/Duration lifetime
bool frame_locked
foxglove_msgs/KeyValuePair[] metadata
foxglove_msgs/ArrowPrimitive[] arrows
foxglove_msgs/CubePrimitive[] cubes
foxglove_msgs/SpherePrimitive[] spheres
foxglove_msgs/CylinderPrimitive[] cylinders
foxglove_msgs/LinePrimitive[] lines
foxglove_msgs/TriangleListPrimitive[] triangles
foxglove_msgs/TextPrimitive[] texts
foxglove_msgs/ModelPrimitive[] models
""",
    "foxglove_msgs/msg/SceneEntityDeletion": """
builtin_interfaces/Time timestamp
uint8 MATCHING_ID=0
uint8 ALL=1
uint8 type
string id
""",
    "foxglove_msgs/msg/SceneUpdate": """
foxglove_msgs/SceneEntityDeletion[] deletions
foxglove_msgs/SceneEntity[] entities
""",
}
