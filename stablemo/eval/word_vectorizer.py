"""GloVe word vectors + POS one-hots for the published Guo et al. text encoder.

The published files are `our_vab_data.npy` (N, 300) float, `our_vab_words.pkl` (a pickled Python
list of N strings: "sos", "eos", "unk", then the vocabulary) and `our_vab_idx.pkl` (a pickled dict
word → row). We never unpickle them: `read_pickled_strings` walks the pickle opcode stream with
`pickletools.genops` (a parser, it executes nothing) and accepts only the opcodes that build lists
or dicts of strings and integers; anything else (GLOBAL, REDUCE, BUILD, ...) is refused.
Alternatively a plain-text `our_vab_words.txt` (one word per line, row order of the .npy) is
used when present; `stablemo data glove-words GLOVE_DIR` writes it from the .pkl with the same
safe reader.
"""

from __future__ import annotations

import pickletools
from pathlib import Path

import numpy as np

from stablemo.errors import StableMoError
from stablemo.io import load_npy, write_text

# 15-class POS one-hot of Guo et al. (text-to-motion `utils/word_vectorizer.py`: POS_enumerator, VIP_dict)
POS_INDEX = {
    "VERB": 0, "NOUN": 1, "DET": 2, "ADP": 3, "NUM": 4, "AUX": 5, "PRON": 6, "ADJ": 7, "ADV": 8,
    "Loc_VIP": 9, "Body_VIP": 10, "Obj_VIP": 11, "Act_VIP": 12, "Desc_VIP": 13, "OTHER": 14,
}
NUM_POS = len(POS_INDEX)

# Words whose tag is replaced by a "very important" class, checked in this order.
VIP_WORDS: dict[str, frozenset[str]] = {
    "Loc_VIP": frozenset("left right clockwise counterclockwise anticlockwise forward back backward up down "
                         "straight curve".split()),
    "Body_VIP": frozenset("arm chin foot feet face hand mouth leg waist eye knee shoulder thigh".split()),
    "Obj_VIP": frozenset("stair dumbbell chair window floor car ball handrail baseball basketball".split()),
    "Act_VIP": frozenset("walk run swing pick bring kick put squat throw hop dance jump turn stumble stop sit "
                         "lift lower raise wash stand kneel stroll rub bend balance flap jog shuffle lean rotate "
                         "spin spread climb".split()),
    "Desc_VIP": frozenset("slowly carefully fast careful slow quickly happy angry sad happily angrily sadly".split()),
}

MAX_TEXT_LEN = 20  # tokens kept; sentences are sos + tokens + eos, padded with unk to 22

# Opcodes that only push strings/ints or assemble lists/dicts: nothing here can call code.
_SAFE_OPS = {
    "PROTO", "FRAME", "STOP", "MARK", "EMPTY_LIST", "EMPTY_DICT", "LIST", "DICT", "APPEND", "APPENDS",
    "SETITEM", "SETITEMS", "BINUNICODE", "SHORT_BINUNICODE", "BINUNICODE8", "UNICODE",
    "BININT", "BININT1", "BININT2", "INT", "LONG", "LONG1", "MEMOIZE", "PUT", "BINPUT", "LONG_BINPUT",
    "GET", "BINGET", "LONG_BINGET",
}


def read_pickled_strings(path: str | Path):
    """Decode a pickle holding only a list of str or a dict str → int, without unpickling.

    A tiny stack machine over `pickletools.genops`; raises StableMoError on any other content.
    """
    path = Path(path)
    if not path.is_file():
        raise StableMoError(f"{path}: file not found")
    stack: list = []
    marks: list[int] = []
    memo: dict[int, object] = {}
    result = None
    try:
        with open(path, "rb") as f:
            for op, arg, _ in pickletools.genops(f):
                name = op.name
                if name not in _SAFE_OPS:
                    raise StableMoError(f"{path}: refusing pickle opcode {name} (only lists/dicts of "
                                        "strings and integers are read)")
                if name in ("PROTO", "FRAME"):
                    continue
                if name == "STOP":
                    result = stack.pop()
                    break
                if name == "MARK":
                    marks.append(len(stack))
                elif name == "EMPTY_LIST":
                    stack.append([])
                elif name == "EMPTY_DICT":
                    stack.append({})
                elif name in ("LIST", "DICT"):
                    start = marks.pop()
                    items, stack[start:] = stack[start:], []
                    stack.append(list(items) if name == "LIST" else dict(zip(items[::2], items[1::2])))
                elif name == "APPEND":
                    value = stack.pop()
                    stack[-1].append(value)
                elif name == "APPENDS":
                    start = marks.pop()
                    items, stack[start:] = stack[start:], []
                    stack[-1].extend(items)
                elif name == "SETITEM":
                    value, key = stack.pop(), stack.pop()
                    stack[-1][key] = value
                elif name == "SETITEMS":
                    start = marks.pop()
                    items, stack[start:] = stack[start:], []
                    stack[-1].update(zip(items[::2], items[1::2]))
                elif name in ("MEMOIZE",):
                    memo[len(memo)] = stack[-1]
                elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
                    memo[int(arg)] = stack[-1]
                elif name in ("GET", "BINGET", "LONG_BINGET"):
                    stack.append(memo[int(arg)])
                elif name in ("INT", "LONG") and isinstance(arg, bool):
                    stack.append(int(arg))
                else:  # string and integer literals
                    stack.append(arg)
    except StableMoError:
        raise
    except Exception as err:  # malformed stream: genops raises ValueError, our stack IndexError/KeyError
        raise StableMoError(f"{path}: unreadable pickle ({err})") from None
    ok_list = isinstance(result, list) and all(isinstance(w, str) for w in result)
    ok_dict = isinstance(result, dict) and all(isinstance(k, str) and isinstance(v, int) for k, v in result.items())
    if not (ok_list or ok_dict):
        raise StableMoError(f"{path}: expected a list of strings or a dict of string → int")
    return result


class WordVectorizer:
    """Maps `word/POS` tokens to (GloVe 300-d vector, 15-d POS one-hot)."""

    def __init__(self, glove_dir: str | Path, prefix: str = "our_vab"):
        glove_dir = Path(glove_dir)
        vectors = load_npy(glove_dir / f"{prefix}_data.npy").astype(np.float32)
        words_txt = glove_dir / f"{prefix}_words.txt"
        if words_txt.is_file():
            words = words_txt.read_text(encoding="utf-8").split("\n")
            words = words[:-1] if words and words[-1] == "" else words
            index = {w: i for i, w in enumerate(words)}
        else:
            words = read_pickled_strings(glove_dir / f"{prefix}_words.pkl")
            idx_file = glove_dir / f"{prefix}_idx.pkl"
            index = read_pickled_strings(idx_file) if idx_file.is_file() else {w: i for i, w in enumerate(words)}
            if not isinstance(index, dict):
                raise StableMoError(f"{idx_file}: expected a dict word → row")
        if not isinstance(words, list):
            raise StableMoError(f"{glove_dir}: words file must hold a list of words")
        if vectors.ndim != 2:
            raise StableMoError(f"{glove_dir / f'{prefix}_data.npy'}: expected (N, dim) vectors, got {vectors.shape}")
        rows = [index.get(w, -1) for w in words]
        if any(r < 0 or r >= len(vectors) for r in rows):
            raise StableMoError(f"{glove_dir}: word index points outside {prefix}_data.npy ({len(vectors)} rows)")
        self.vectors = vectors
        self.row = dict(zip(words, rows))
        if "unk" not in self.row:
            raise StableMoError(f"{glove_dir}: vocabulary has no 'unk' entry")

    @property
    def dim(self) -> int:
        return self.vectors.shape[1]

    def __len__(self) -> int:
        return len(self.row)

    @staticmethod
    def pos_onehot(tag: str) -> np.ndarray:
        vec = np.zeros(NUM_POS, np.float32)
        vec[POS_INDEX.get(tag, POS_INDEX["OTHER"])] = 1.0
        return vec

    def __getitem__(self, token: str) -> tuple[np.ndarray, np.ndarray]:
        word, _, tag = token.partition("/")
        if word not in self.row:
            return self.vectors[self.row["unk"]], self.pos_onehot("OTHER")
        for vip, words in VIP_WORDS.items():
            if word in words:
                tag = vip
                break
        return self.vectors[self.row[word]], self.pos_onehot(tag)

    def encode_tokens(self, tokens: list[str]) -> tuple[np.ndarray, np.ndarray, int]:
        """`word/POS` tokens → word vectors (22, 300), POS one-hots (22, 15), sentence length."""
        tokens = ["sos/OTHER", *tokens[:MAX_TEXT_LEN], "eos/OTHER"]
        length = len(tokens)
        tokens += ["unk/OTHER"] * (MAX_TEXT_LEN + 2 - length)
        words, tags = zip(*(self[t] for t in tokens))
        return np.stack(words), np.stack(tags), length


def tokens_from_caption(caption: str) -> list[str]:
    """Fallback tokens for a caption without tags: lower-cased words, POS "OTHER" (VIP lists still apply).

    The published evaluator expects spaCy-lemmatised tokens as stored in the dataset text files; use
    those whenever they exist, this only keeps generation-only captions scorable.
    """
    words = "".join(c if c.isalnum() or c.isspace() else " " for c in caption.lower()).split()
    return [f"{w}/OTHER" for w in words]


def convert_words_to_text(glove_dir: str | Path, prefix: str = "our_vab") -> Path:
    """Write `<prefix>_words.txt` (row order of the .npy) from the pickled words/idx files, safely."""
    glove_dir = Path(glove_dir)
    words = read_pickled_strings(glove_dir / f"{prefix}_words.pkl")
    idx_file = glove_dir / f"{prefix}_idx.pkl"
    index = read_pickled_strings(idx_file) if idx_file.is_file() else {w: i for i, w in enumerate(words)}
    if not isinstance(words, list) or not isinstance(index, dict):
        raise StableMoError(f"{glove_dir}: expected a word list and a word → row dict")
    by_row = sorted(words, key=lambda w: index[w])
    if [index[w] for w in by_row] != list(range(len(by_row))) or any("\n" in w for w in by_row):
        raise StableMoError(f"{glove_dir}: word rows are not a permutation of 0..N-1")
    out = glove_dir / f"{prefix}_words.txt"
    write_text(out, "\n".join(by_row) + "\n")
    return out

