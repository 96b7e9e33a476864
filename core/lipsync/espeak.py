"""Speech synthesis with phoneme timings from the eSpeak NG library (ctypes, no extra package).

How the timings are obtained (the most accurate of the options tried): the library
``libespeak-ng.so.1`` is initialised in synchronous mode with *phoneme events* and *IPA names*
(``espeakINITIALIZE_PHONEME_EVENTS | espeakINITIALIZE_PHONEME_IPA``); one ``espeak_Synth`` call
then hands the synthesis callback both the audio samples and an ``espeakEVENT_PHONEME`` event at the
start of every phoneme, carrying its sample position in that same audio. So the phonemes and the
WAV come from one synthesis and agree to the sample — this is thesis A's "phoneme event callback
of the TTS library", done offline. Rejected: ``--pho`` needs MBROLA voices (not installed);
``-x``/``--ipa`` print phonemes without times; timing words by synthesising them one by one
loses coarticulation and the sentence rhythm.

A phoneme lasts until the next phoneme event (the last one until the end of the audio). Pauses
come as events with an empty name and are returned as ``"_"``. Symbols are IPA as eSpeak writes
them (``"aʊ"``, ``"dʒ"``, ``"ɐ̃"``; stress marks are not part of phoneme events).

The library keeps global state, so calls are serialised by a lock.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import re
import threading
from dataclasses import dataclass

import numpy as np

#: Mimica language -> eSpeak NG voice. "en" is American English (the TTS voices of thesis A's time).
VOICES = {"en": "en-us", "en-us": "en-us", "en-gb": "en", "pt-br": "pt-br"}
MAX_TEXT_CHARS = 20_000
PAUSE = "_"
_LANGUAGE_SWITCH = re.compile(r"^\([\w-]+\)$")

_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INIT_PHONEME_EVENTS, _INIT_PHONEME_IPA, _INIT_DONT_EXIT = 0x0001, 0x0002, 0x8000
_CHARS_UTF8, _ENDPAUSE = 1, 0x1000
_POS_CHARACTER = 1
_EVENT_LIST_TERMINATED, _EVENT_END, _EVENT_MSG_TERMINATED, _EVENT_PHONEME = 0, 5, 6, 7
_RATE = 1


class SpeechError(RuntimeError):
    """eSpeak NG is missing or failed; the message says what to install or check."""


class LanguageError(ValueError):
    """An unsupported language code."""


@dataclass(frozen=True)
class Phoneme:
    """One phoneme of synthesised speech: IPA symbol (``"_"`` = pause), start and duration in s."""

    symbol: str
    start_s: float
    duration_s: float

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


@dataclass(frozen=True)
class Synthesis:
    """samples : (n,) int16 mono audio; sample_rate : Hz; phonemes covering [0, n / sample_rate]."""

    samples: np.ndarray
    sample_rate: int
    phonemes: tuple[Phoneme, ...]

    @property
    def duration_s(self) -> float:
        return len(self.samples) / self.sample_rate


class _Id(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):  # espeak_EVENT (speak_lib.h)
    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint), ("text_position", ctypes.c_int),
                ("length", ctypes.c_int), ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _Id)]


_Callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))
_lock = threading.Lock()
_state: dict = {}


def _library_names() -> list[str]:
    names = [ctypes.util.find_library("espeak-ng")]
    if sys.platform == "darwin":
        names += ["libespeak-ng.1.dylib", "libespeak-ng.dylib", "/opt/homebrew/lib/libespeak-ng.dylib"]
    elif sys.platform == "win32":
        names += ["libespeak-ng.dll", r"C:\Program Files\eSpeak NG\libespeak-ng.dll"]
    else:
        names += ["libespeak-ng.so.1", "libespeak-ng.so"]
    return [n for n in names if n]


def _init() -> dict:
    """Load and initialise the library once per process (call with the lock held)."""
    if _state:
        return _state
    lib = None
    for name in _library_names():
        try:
            lib = ctypes.CDLL(name)
            break
        except OSError:
            continue
    if lib is None:
        raise SpeechError("lip-sync needs the eSpeak NG library (libespeak-ng), which was not found; install it, "
                          "e.g. 'sudo apt install espeak-ng' or from https://github.com/espeak-ng/espeak-ng/releases")
    lib.espeak_Initialize.restype = ctypes.c_int
    lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    lib.espeak_SetSynthCallback.argtypes = [_Callback]
    lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
    lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lib.espeak_Synth.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int, ctypes.c_uint,
                                 ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    rate = lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, None,
                                 _INIT_PHONEME_EVENTS | _INIT_PHONEME_IPA | _INIT_DONT_EXIT)
    if rate <= 0:
        raise SpeechError("eSpeak NG could not start (its data folder espeak-ng-data may be missing); reinstall it")
    sink: dict = {"chunks": [], "events": []}

    def callback(wav, n, events):
        if n > 0 and wav:
            sink["chunks"].append(ctypes.string_at(wav, 2 * n))
        i = 0
        while events[i].type != _EVENT_LIST_TERMINATED:
            e = events[i]
            if e.type == _EVENT_PHONEME:
                sink["events"].append((e.sample, bytes(e.id.string).split(b"\0")[0].decode("utf-8", "replace")))
            i += 1
        return 0

    cb = _Callback(callback)
    lib.espeak_SetSynthCallback(cb)
    _state.update(lib=lib, rate=rate, sink=sink, callback=cb, voice=None)
    return _state


def voice_for(lang: str) -> str:
    """The eSpeak NG voice for a Mimica language code; LanguageError lists the supported ones."""
    try:
        return VOICES[lang.strip().lower()]
    except (KeyError, AttributeError):
        raise LanguageError(f"unsupported language {lang!r}; Mimica speaks {', '.join(VOICES)}") from None


def synthesize(text: str, lang: str = "en", *, rate_wpm: int = 175) -> Synthesis:
    """Speak ``text`` with eSpeak NG: audio samples and timed phonemes from the same synthesis.

    rate_wpm : speaking rate, words per minute (80..450).
    """
    voice = voice_for(lang)
    if not isinstance(text, str) or not text.strip():
        raise ValueError("there is no text to speak: type a sentence first")
    if len(text) > MAX_TEXT_CHARS:
        raise ValueError(f"the text has {len(text)} characters; lip-sync takes at most {MAX_TEXT_CHARS} at once, "
                         "split it into several clips")
    if not 80 <= int(rate_wpm) <= 450:
        raise ValueError(f"speaking rate must be 80 to 450 words per minute, got {rate_wpm}")
    data = text.encode("utf-8") + b"\0"
    with _lock:
        st = _init()
        lib, sink = st["lib"], st["sink"]
        if st["voice"] != voice:
            if lib.espeak_SetVoiceByName(voice.encode()) != 0:
                raise SpeechError(f"eSpeak NG has no voice {voice!r}; reinstall espeak-ng-data")
            st["voice"] = voice
        lib.espeak_SetParameter(_RATE, int(rate_wpm), 0)
        sink["chunks"].clear(), sink["events"].clear()
        err = lib.espeak_Synth(data, len(data), 0, _POS_CHARACTER, 0, _CHARS_UTF8 | _ENDPAUSE, None, None)
        lib.espeak_Synchronize()
        if err != 0:
            raise SpeechError(f"eSpeak NG failed to speak the text (error {err})")
        samples = np.frombuffer(b"".join(sink["chunks"]), dtype="<i2").copy()
        events = list(sink["events"])
        sample_rate = st["rate"]
    return Synthesis(samples, sample_rate, _phonemes(events, len(samples), sample_rate))


def _phonemes(events: list[tuple[int, str]], n_samples: int, rate: int) -> tuple[Phoneme, ...]:
    """Phonemes covering [0, n_samples): silence before the first event, each until the next event.

    Language-switch markers such as ``(en)`` (eSpeak speaking a foreign word) are not sounds: their
    time goes to the phoneme before them.
    """
    cuts: list[tuple[int, str]] = []
    for sample, name in events:
        symbol = name.replace("ˈ", "").replace("ˌ", "").strip() or PAUSE
        sample = max(0, min(int(sample), n_samples))
        if _LANGUAGE_SWITCH.match(symbol):
            continue
        if cuts and sample <= cuts[-1][0]:
            cuts[-1] = (cuts[-1][0], symbol)  # two events at one sample: the later one names it
            continue
        cuts.append((sample, symbol))
    if not cuts or cuts[0][0] > 0:
        cuts.insert(0, (0, PAUSE))
    out = []
    for (a, symbol), (b, _) in zip(cuts, cuts[1:] + [(n_samples, "")]):
        if b > a:
            out.append(Phoneme(symbol, a / rate, (b - a) / rate))
    return tuple(out)


def espeak_version() -> str:
    """The library's version string (part of the speech cache key)."""
    with _lock:
        lib = _init()["lib"]
    lib.espeak_Info.restype = ctypes.c_char_p
    lib.espeak_Info.argtypes = [ctypes.c_void_p]
    return (lib.espeak_Info(None) or b"?").decode()
