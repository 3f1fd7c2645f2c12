"""Image/CameraInfo pairing by stamp, in every arrival order (no ROS)."""

from planar_vo.ros.pairing import Pairing


def _pairs(ready):
    return [(p.image, p.info, p.exact) for p in ready]


def test_camera_info_first_pairs_at_once():
    pairing = Pairing()
    assert pairing.add_info(1, 'info1') == []
    assert _pairs(pairing.add_image(1, 'img1')) == [('img1', 'info1', True)]
    assert not pairing.unmatched


def trusted():
    """A Pairing that has seen stamps match (images then wait for their own)."""
    pairing = Pairing()
    for k in range(3):
        pairing.add_info(k, f'info{k}')
        assert pairing.add_image(k, f'img{k}')[0].exact
    return pairing


def test_image_first_waits_for_its_own_camera_info():
    pairing = trusted()
    assert pairing.add_image(5, 'img5') == []  # the old CameraInfo is not used
    assert _pairs(pairing.add_info(5, 'info5')) == [('img5', 'info5', True)]
    assert not pairing.unmatched


def test_from_the_start_an_image_waits_for_its_camera_info():
    pairing = Pairing()
    pairing.add_info(1, 'info1')
    assert pairing.add_image(2, 'img2') == [] and pairing.waiting
    assert _pairs(pairing.add_info(2, 'info2')) == [('img2', 'info2', True)]


def test_a_camera_info_sent_again_releases_the_waiting_image():
    pairing = trusted()
    assert pairing.add_image(5, 'img5') == []
    assert _pairs(pairing.add_info(2, 'info2 again')) == [('img5', 'info2 again', False)]
    assert not pairing.unmatched  # one miss is not a driver that never matches


def test_after_a_camera_info_sent_again_images_do_not_wait():
    pairing = trusted()
    pairing.add_info(2, 'info2 again')  # a driver re-sending its one CameraInfo
    assert _pairs(pairing.add_image(5, 'img5')) == [('img5', 'info2 again', False)]


def test_orders_mixed_and_camera_info_at_a_higher_rate():
    pairing = trusted()
    got = []
    for k in range(3, 20):
        if k % 2:  # image before its CameraInfo
            got += pairing.add_image(10 * k, f'img{k}')
            got += pairing.add_info(10 * k, f'info{k}')
            got += pairing.add_info(10 * k + 5, f'info{k}.5')  # CameraInfo at twice the rate
        else:
            got += pairing.add_info(10 * k, f'info{k}')
            got += pairing.add_image(10 * k, f'img{k}')
    assert _pairs(got) == [(f'img{k}', f'info{k}', True) for k in range(3, 20)]


def test_stamps_that_stop_matching_use_the_newest_without_waiting():
    pairing = trusted()
    got = []
    for k in range(3, 13):  # the driver now stamps CameraInfo 1 ns before the image
        got += pairing.add_info(10 * k - 1, f'info{k}')
        got += pairing.add_image(10 * k, f'img{k}')
    # Three images waited for the next message; after that each goes out at once.
    assert [p.image for p in got] == [f'img{k}' for k in range(3, 13)]
    assert all(not p.exact for p in got) and pairing.unmatched
    assert _pairs(got)[:3] == [(f'img{k}', f'info{k + 1}', False) for k in range(3, 6)]
    assert _pairs(got)[3:] == [(f'img{k}', f'info{k}', False) for k in range(6, 13)]


def test_stamps_matching_again_make_images_wait_again():
    pairing = trusted()
    for k in range(3, 9):  # misses: unmatched
        pairing.add_info(10 * k - 1, f'info{k}')
        pairing.add_image(10 * k, f'img{k}')
    assert pairing.unmatched
    for k in range(9, 12):
        pairing.add_info(10 * k, f'info{k}')
        assert pairing.add_image(10 * k, f'img{k}')[0].exact
    assert not pairing.unmatched
    assert pairing.add_image(200, 'img20') == [] and pairing.waiting


def test_camera_info_at_a_lower_rate_does_not_hold_images_back():
    pairing = trusted()
    ready_at_arrival = []
    for k in range(30):
        if k % 10 == 0:
            pairing.add_info(100 + k, f'info{k}')
        ready = pairing.add_image(100 + k, f'img{k}')
        ready_at_arrival.append([p.image for p in ready])
    # Images 1-3 waited for one frame; from then on every image is ready when it arrives.
    assert all(ready == [f'img{k}'] for k, ready in enumerate(ready_at_arrival) if k >= 5)
    assert ready_at_arrival[4] == ['img3', 'img4']
    assert pairing.unmatched


def test_images_before_any_camera_info_have_none():
    pairing = Pairing()
    assert _pairs(pairing.add_image(1, 'a')) == [('a', None, False)]
    assert _pairs(pairing.add_image(2, 'b')) == [('b', None, False)]
    assert not pairing.unmatched
    pairing.add_info(3, 'info3')
    assert _pairs(pairing.add_image(3, 'c')) == [('c', 'info3', True)]


def test_flush_releases_the_waiting_image():
    pairing = trusted()
    assert pairing.add_image(5, 'last') == []
    assert _pairs(pairing.flush()) == [('last', 'info2', False)]
    assert pairing.flush() == []


def test_only_the_last_few_camera_infos_are_kept():
    pairing = Pairing(keep=3)
    for k in range(5):
        pairing.add_info(k, f'info{k}')
    assert _pairs(pairing.add_image(1, 'old')) == [('old', 'info4', False)]
    assert _pairs(pairing.add_image(3, 'recent')) == [('recent', 'info3', True)]
