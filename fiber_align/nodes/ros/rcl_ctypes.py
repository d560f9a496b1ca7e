# SPDX-License-Identifier: Apache-2.0
"""
The rcl and rcutils calls of the sender thread, bound by ``ctypes`` (the GIL released).

:class:`Rcl` binds ``rcl_publish``, the matched-reader count, ``rcutils_log`` and the
graph's topic listing and publisher counts from the ``librcl.so`` rclpy loaded;
:class:`MessageType` makes the C message of a Python one as rclpy's ``publish`` does.
Used by :mod:`fiber_align.nodes.ros.sender` and :mod:`fiber_align.nodes.ros.owners`.
"""

import ctypes


class Rcl:
    """The rcl calls of the sender thread, bound from the librcl rclpy loaded."""

    def __init__(self):
        """Find the loaded ``librcl.so`` and bind the calls (GIL released in each)."""
        with open('/proc/self/maps') as f:
            paths = [ln.split()[-1] for ln in f if ln.rstrip().endswith('/librcl.so')]
        if not paths:
            raise OSError('librcl.so is not loaded (import rclpy first)')
        lib = ctypes.CDLL(paths[0])
        self.publish = lib.rcl_publish
        self.publish.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        self.publish.restype = ctypes.c_int
        self.count = lib.rcl_publisher_get_subscription_count
        self.count.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
        self.count.restype = ctypes.c_int
        self.count_publishers = lib.rcl_count_publishers
        self.count_publishers.argtypes = [ctypes.c_void_p, ctypes.c_char_p,
                                          ctypes.POINTER(ctypes.c_size_t)]
        self.count_publishers.restype = ctypes.c_int
        ut = ctypes.CDLL(paths[0].replace('/librcl.so', '/librcutils.so'))
        self.reset_error = ut.rcutils_reset_error
        self.reset_error.argtypes = []
        self.reset_error.restype = None
        self.log = ut.rcutils_log       # (location, severity, name, format, ...)
        self.log.restype = None
        self.topics = lib.rcl_get_topic_names_and_types
        self.topics.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Allocator), ctypes.c_bool,
                                ctypes.POINTER(_NamesAndTypes)]
        self.topics.restype = ctypes.c_int
        self.topics_fini = lib.rcl_names_and_types_fini
        self.topics_fini.argtypes = [ctypes.POINTER(_NamesAndTypes)]
        self.topics_fini.restype = ctypes.c_int
        default_allocator = ut.rcutils_get_default_allocator
        default_allocator.argtypes = []
        default_allocator.restype = _Allocator
        self.allocator = default_allocator()

    def topic_names_and_types(self, node_ptr):
        """
        Return the graph's ``[(topic, [type, ...]), ...]`` as seen by an rcl node.

        rclpy's ``get_topic_names_and_types`` (the same rcl call); ``None`` if it failed.
        """
        nat = _NamesAndTypes()
        if self.topics(node_ptr, ctypes.byref(self.allocator), False, ctypes.byref(nat)):
            self.reset_error()
            return None
        try:
            return [(nat.names.data[i].decode(),
                     [nat.types[i].data[k].decode() for k in range(nat.types[i].size)])
                    for i in range(nat.names.size)]
        finally:
            if self.topics_fini(ctypes.byref(nat)):
                self.reset_error()


class _Allocator(ctypes.Structure):
    """``rcutils_allocator_t``."""

    _fields_ = [('allocate', ctypes.c_void_p), ('deallocate', ctypes.c_void_p),
                ('reallocate', ctypes.c_void_p), ('zero_allocate', ctypes.c_void_p),
                ('state', ctypes.c_void_p)]


class _StringArray(ctypes.Structure):
    """``rcutils_string_array_t``."""

    _fields_ = [('size', ctypes.c_size_t), ('data', ctypes.POINTER(ctypes.c_char_p)),
                ('allocator', _Allocator)]


class _NamesAndTypes(ctypes.Structure):
    """``rcl_names_and_types_t`` (zero-initialised as ctypes makes it)."""

    _fields_ = [('names', _StringArray), ('types', ctypes.POINTER(_StringArray))]


class Location(ctypes.Structure):
    """``rcutils_log_location_t``: where a log line was written."""

    _fields_ = [('function_name', ctypes.c_char_p), ('file_name', ctypes.c_char_p),
                ('line_number', ctypes.c_size_t)]


def c_text(text):
    """Return ``text`` as UTF-8 bytes for a C string (undecodable characters replaced)."""
    return str(text).encode('utf-8', 'replace')


class MessageType:
    """
    The C side of a message type, as rclpy's ``publish`` uses it (from its metaclass).

    :meth:`to_c` makes the C message of a Python one (the GIL held, it reads Python
    objects); :meth:`destroy` frees it (no GIL needed).
    """

    _get = None

    def __init__(self, msg_type):
        """Bind the type support's create, convert and destroy functions."""
        if MessageType._get is None:
            get = ctypes.pythonapi.PyCapsule_GetPointer
            get.restype = ctypes.c_void_p
            get.argtypes = [ctypes.py_object, ctypes.c_char_p]
            MessageType._get = get
        meta = type(msg_type)         # its type support is imported by create_publisher
        get = MessageType._get
        self._create = ctypes.CFUNCTYPE(ctypes.c_void_p)(get(meta._CREATE_ROS_MESSAGE, None))
        self._convert = ctypes.PYFUNCTYPE(ctypes.c_bool, ctypes.py_object, ctypes.c_void_p)(
            get(meta._CONVERT_FROM_PY, None))
        self.destroy = ctypes.CFUNCTYPE(None, ctypes.c_void_p)(
            get(meta._DESTROY_ROS_MESSAGE, None))

    def to_c(self, msg):
        """Return the address of a new C message equal to ``msg`` (free: :meth:`destroy`)."""
        ptr = self._create()
        if not ptr:
            raise MemoryError('cannot allocate a %s' % type(msg).__name__)
        if not self._convert(msg, ptr):
            self.destroy(ptr)
            raise TypeError('cannot convert a %s' % type(msg).__name__)
        return ptr
