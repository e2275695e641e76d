pytest_plugins = ['im_bringup.testing']
