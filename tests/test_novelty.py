import imagehash
import numpy as np
import pytest
from PIL import Image

from babblegen import state_file
from babblegen.descriptors import (
    PHash,
    from_hex,
    make_descriptor,
    pack_bits,
    to_hex,
    unpack_bits,
)
from babblegen.novelty import Archive, MostNovel, hamming, k_smallest_distances, novelty


def codes(*values: int) -> np.ndarray:
    return np.array(values, dtype=np.uint64)[:, None]


# population p0..p3 = 0b0000, 0b0001, 0b0011, 0b1111; archive a0, a1 = 0b0111, 0xFF
POP = codes(0b0000, 0b0001, 0b0011, 0b1111)
ARC = codes(0b0111, 0xFF)
# Hamming distances worked out bit by bit:
#        p0 p1 p2 p3 | a0 a1
#   p0    -  1  2  4 |  3  8
#   p1    1  -  1  3 |  2  7
#   p2    2  1  -  2 |  1  6
#   p3    4  3  2  - |  1  4


def test_hamming_hand_made():
    expected = np.array([[3, 8], [2, 7], [1, 6], [1, 4]])
    np.testing.assert_array_equal(hamming(POP, ARC), expected)
    np.testing.assert_array_equal(np.diag(hamming(POP, POP)), 0)


def test_hamming_multiword_adds_words():
    a = np.array([[0, 0]], dtype=np.uint64)
    b = np.array([[2**64 - 1, 1], [0, 2**63]], dtype=np.uint64)
    np.testing.assert_array_equal(hamming(a, b), [[65, 1]])


def test_hamming_matches_python_popcount_across_chunks():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 2**64, size=(24, 2), dtype=np.uint64)
    b = rng.integers(0, 2**64, size=(50_000, 2), dtype=np.uint64)  # several chunks
    d = hamming(a, b)
    for i, j in [(0, 0), (3, 17), (23, 49_999), (11, 25_000)]:
        ref = sum(bin(int(x) ^ int(y)).count("1") for x, y in zip(a[i], b[j], strict=True))
        assert d[i, j] == ref


def test_k_smallest_matches_full_sort_across_chunks():
    rng = np.random.default_rng(1)
    for words in (1, 3):
        q = rng.integers(0, 2**64, size=(24, words), dtype=np.uint64)
        refs = rng.integers(0, 2**64, size=(100_000, words), dtype=np.uint64)
        full = np.sort(hamming(q, refs), axis=1)[:, :4]
        np.testing.assert_array_equal(k_smallest_distances(q, refs, 4), full)


def test_novelty_hand_made_with_archive():
    # k = 3 nearest among the other population members and the archive (own entry excluded):
    #   p0: 1 2 3 -> 2      p1: 1 1 2 -> 4/3      p2: 1 1 2 -> 4/3      p3: 1 2 3 -> 2
    nov = novelty(POP, POP, ARC, k=3)
    np.testing.assert_allclose(nov, [2.0, 4 / 3, 4 / 3, 2.0])


def test_novelty_hand_made_without_archive():
    #   p0: 1 2 4 -> 7/3    p1: 1 1 3 -> 5/3      p2: 1 2 2 -> 5/3      p3: 2 3 4 -> 3
    np.testing.assert_allclose(novelty(POP, POP, None, k=3), [7 / 3, 5 / 3, 5 / 3, 3.0])
    np.testing.assert_allclose(novelty(POP, POP, ARC[:0], k=3), [7 / 3, 5 / 3, 5 / 3, 3.0])


def test_novelty_subset_of_population_as_queries():
    # queries p1, p3 against the same population and archive: 4/3 and 2 as above
    np.testing.assert_allclose(novelty(POP[[1, 3]], POP, ARC, k=3), [4 / 3, 2.0])


def test_novelty_fewer_than_k_neighbours_averages_what_exists():
    # p0, p1 alone: each has one neighbour at distance 1
    np.testing.assert_allclose(novelty(POP[:2], POP[:2], None, k=3), [1.0, 1.0])
    # a lone individual has no neighbour at all: novelty 0
    np.testing.assert_allclose(novelty(POP[:1], POP[:1], None, k=3), [0.0])
    # a lone individual and the archive: p3 to a0 = 1, a1 = 4 -> 2.5
    np.testing.assert_allclose(novelty(POP[3:], POP[3:], ARC, k=3), [2.5])


def test_novelty_duplicates_count_as_neighbours():
    # population [0, 0, 0b1111], k = 2: each 0 sees the other 0 (0) and 0b1111 (4) -> 2; 0b1111 sees 4, 4 -> 4
    pop = codes(0, 0, 0b1111)
    np.testing.assert_allclose(novelty(pop, pop, None, k=2), [2.0, 2.0, 4.0])


def test_novelty_external_queries():
    # query 0b1000 is not in the population: distances to p0..p3 = 1, 2, 3, 3; a0, a1 = 4, 7 -> k=2: 1.5
    q = codes(0b1000)
    np.testing.assert_allclose(novelty(q, POP, ARC, k=2, self_in_population=False), [1.5])
    with pytest.raises(ValueError):
        novelty(q, POP, ARC, k=2, self_in_population=True)


def test_archive_grows_and_round_trips():
    arc = Archive(capacity=2)
    for v in range(5):
        assert arc.add(np.array([v, 2 * v], dtype=np.uint64), {"index": v}) == v
    assert len(arc) == 5
    np.testing.assert_array_equal(arc.descriptors[:, 0], np.arange(5))
    np.testing.assert_array_equal(arc.descriptors[:, 1], 2 * np.arange(5))
    assert [m["index"] for m in arc.meta] == list(range(5))
    with pytest.raises(ValueError):
        arc.descriptors[0, 0] = 7  # read-only view
    with pytest.raises(ValueError):
        arc.add(np.array([1], dtype=np.uint64))  # wrong width

    restored = Archive()
    restored.load_state_dict(state_file.loads(state_file.dumps(arc.state_dict())))
    np.testing.assert_array_equal(restored.descriptors, arc.descriptors)
    assert restored.meta == arc.meta
    restored.add(np.array([9, 9], dtype=np.uint64))
    assert len(restored) == 6 and len(arc) == 5


def test_most_novel_policy_breaks_ties_by_index():
    nov = np.array([1.0, 3.0, 2.0, 3.0])
    np.testing.assert_array_equal(MostNovel(1).select(nov, None, Archive()), [1])
    np.testing.assert_array_equal(MostNovel(3).select(nov, None, Archive()), [1, 3, 2])
    assert MostNovel(0).select(nov, None, Archive()).size == 0


# ----------------------------------------------------------------------------- descriptors


def synthetic_image(h: int = 96, w: int = 128, shift: int = 0) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[..., 0] = (255 * x / (w - 1)).astype(np.uint8)
    img[..., 1] = (255 * y / (h - 1)).astype(np.uint8)
    img[20:50, 30 + shift : 70 + shift] = (250, 30, 40)  # a red box
    rr = (y - 70) ** 2 + (x - 100) ** 2 < 15**2
    img[rr] = (20, 20, 220)  # a blue disc
    return img


def test_phash_hex_matches_imagehash():
    img = synthetic_image()
    desc = PHash()
    code = desc(img)
    assert code.dtype == np.uint64 and code.shape == (1,)
    expected = str(imagehash.phash(Image.fromarray(img)))
    assert len(expected) == 16
    assert to_hex(code) == expected
    assert desc.hex(code) == expected
    np.testing.assert_array_equal(from_hex(expected, 1), code)


def test_phash_hamming_matches_imagehash_difference():
    a, b = synthetic_image(), synthetic_image(shift=40)
    da, db = PHash()(a), PHash()(b)
    ref = imagehash.phash(Image.fromarray(a)) - imagehash.phash(Image.fromarray(b))
    assert ref > 0
    assert hamming(da[None], db[None])[0, 0] == ref


def test_phash16_and_odd_sizes_match_imagehash():
    img = synthetic_image()
    d16 = make_descriptor("phash16")
    assert d16.n_bits == 256
    c16 = d16(img)
    assert c16.shape == (4,)
    assert d16.hex(c16) == str(imagehash.phash(Image.fromarray(img), hash_size=16))
    d6 = PHash(hash_size=6)  # 36 bits, padded in front of one word
    c6 = d6(img)
    assert d6.hex(c6) == str(imagehash.phash(Image.fromarray(img), hash_size=6))
    assert int(c6[0]) < 2**36


def test_phash_crop_hashes_the_cropped_region():
    img = synthetic_image()
    desc = PHash(crop=(0.0, 0.25, 0.5, 1.0))
    expected = str(imagehash.phash(Image.fromarray(img[24:96, 0:64])))
    assert desc.hex(desc(img)) == expected
    rebuilt = make_descriptor(**desc.config())
    assert rebuilt.config() == desc.config()
    with pytest.raises(ValueError):
        PHash(crop=(0.5, 0.0, 0.4, 1.0))


def test_hex_and_bit_packing_round_trip():
    rng = np.random.default_rng(5)
    for n_words in (1, 2, 4):
        words = rng.integers(0, 2**64, size=n_words, dtype=np.uint64)
        np.testing.assert_array_equal(from_hex(to_hex(words), n_words), words)
    bits = rng.random(100) < 0.5
    packed = pack_bits(bits)
    assert packed.shape == (2,)
    np.testing.assert_array_equal(unpack_bits(packed, 100), bits)
    # bit order: most significant first, as imagehash reads its array
    assert to_hex(pack_bits(np.array([1, 0, 0, 0, 0, 0, 0, 1], dtype=bool)), 8) == "81"
    with pytest.raises(ValueError):
        from_hex("1" + "0" * 16, 1)


def test_descriptor_rejects_non_image():
    with pytest.raises(ValueError):
        PHash()(np.zeros((4, 4), dtype=np.float32))
    with pytest.raises(ValueError):
        make_descriptor("nope")
