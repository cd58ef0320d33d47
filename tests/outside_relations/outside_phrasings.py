"""Our own phrasing set for the room in outside_room.py (written for this client, not taken
from the project's tests or grammar tables).

Each relational entry: (question, acceptable answers by our key, asker position or None).
The asker's position goes as `&from=x,y,z` (docs/protocol.md). A question about "anything"
that several things satisfy lists them all.
"""

# where an asker stands (x, y, eye height z)
BY_THE_READING_CORNER = (1.0, 3.0, 1.6)
BY_THE_SOFA_END = (5.2, 3.2, 1.6)
AT_THE_KETTLE = (4.6, 1.3, 1.6)
AT_THE_DOOR = (0.3, 1.9, 1.6)

RELATIONAL = [
    # mugs: three, on three different surfaces
    ("which mug is on the desk", {"mug_desk"}, None),
    ("the cup sitting on the counter", {"mug_counter"}, None),
    ("my mug on the kitchen counter", {"mug_counter"}, None),
    ("the mug up on the shelf", {"mug_shelf"}, None),
    ("the highest mug", {"mug_shelf"}, None),
    ("the lowest mug", {"mug_desk"}, None),
    ("the mug next to the kettle", {"mug_counter"}, None),
    ("the mug near the laptop", {"mug_desk"}, None),
    ("the mug nearest to me", {"mug_counter"}, AT_THE_KETTLE),
    # chairs: one at the desk, one at the dining table, one beside the sofa
    ("which chair is next to the sofa", {"chair_sofa"}, None),
    ("the chair beside the couch", {"chair_sofa"}, None),
    ("the chair near the desk", {"chair_desk"}, None),
    ("the chair at the desk", {"chair_desk"}, None),
    ("the chair by the dining table", {"chair_table"}, None),
    ("the chair closest to the table", {"chair_table"}, None),
    ("the chair farthest from the sofa", {"chair_desk"}, None),
    # bags: one on a chair, one under the table
    ("the bag on the chair", {"bag_on_chair"}, None),
    ("which bag is under the table", {"bag_under_table"}, None),
    ("anything under the dining table", {"bag_under_table"}, None),
    ("the bag near the desk", {"bag_on_chair"}, None),
    ("the smallest bag", {"bag_on_chair"}, None),
    # lamps: one on the side table, one standing by the sofa
    ("the lamp on the side table", {"table_lamp"}, None),
    ("the lamp next to the sofa", {"floor_lamp"}, None),
    ("the lamp nearest to me", {"table_lamp"}, BY_THE_READING_CORNER),
    ("the lamp closest to me", {"floor_lamp"}, BY_THE_SOFA_END),
    ("the highest lamp", {"floor_lamp"}, None),
    ("the biggest lamp", {"floor_lamp"}, None),
    # books
    ("the book on the dining table", {"book_table"}, None),
    ("the books on the desk", {"books_desk"}, None),
    ("which book is next to the laptop", {"books_desk"}, None),
    ("the book farthest from me", {"book_table"}, AT_THE_DOOR),
    # any thing
    ("what's on the shelf", {"mug_shelf"}, None),
    ("what is under the desk", {"bin"}, None),
    ("anything on the sofa", {"cushion"}, None),
    ("what is on the side table", {"table_lamp"}, None),
    ("what's on the dining table", {"book_table", "bottle"}, None),
    ("the thing between the desk and the dining table", {"box"}, None),
    ("the box between the desk and the table", {"box"}, None),
    ("the largest table", {"dining_table"}, None),
    ("the cushion on the couch", {"cushion"}, None),
]

# nothing in the room stands in these relations: each should answer match: false
NEGATIVE = [
    "the mug under the sofa",
    "the bag on the shelf",
    "the lamp on the desk",
    "the chair on the dining table",
    "the kettle on the desk",
    "the book under the sofa",
    "the laptop on the kitchen counter",
    "the bottle on the shelf",
    "the cushion under the dining table",
    "the plant on the sofa",
]

# no relation: answered as plain questions (relation null)
PLAIN = [
    ("where is my laptop", {"laptop"}),
    ("the kettle", {"kettle"}),
    ("where did I put the trash can", {"bin"}),
    ("find the plant", {"plant"}),
    ("sofa", {"sofa"}),
    ("where's the cardboard box", {"box"}),
    ("a bottle", {"bottle"}),
    ("the kitchen counter", {"counter"}),
    ("my desk", {"desk"}),
    ("cushion", {"cushion"}),
]
